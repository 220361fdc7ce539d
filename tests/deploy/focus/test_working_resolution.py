"""--method focus's automatic working resolution (aat_deploy.focus.scale) and the streaming decode that feeds it
(aat_deploy.infer.process.fitted_frames): the blur step measured from the frames against the step the test rendered,
the rule's hand cases, and that no frame is decoded more often than the rule needs."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from aat_deploy.focus import scale
from aat_deploy.focus.runner import FocusMethod
from aat_deploy.infer.process import depth_from_frames, fitted_frames


def stack_with_step(sigma_step: float, h: int = 480, w: int = 640, s: int = 6, seed: int = 0) -> list[np.ndarray]:
    """Frames (H, W, 3) of a scene of vertical strips at the frames' own focus positions and between them, blurred
    with a Gaussian whose sigma grows by sigma_step per frame interval of defocus (blur linear in diopters)."""
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.random((h, w, 3)).astype(np.float32), (0, 0), 0.6)
    pos = np.repeat(np.linspace(0, s - 1, 2 * s - 1), w // (2 * s - 1) + 1)[:w]  # in-focus frame index per column
    frames = []
    for f in range(s):
        out = np.empty_like(tex)
        for p in np.unique(pos):
            sig = sigma_step * abs(p - f)
            layer = cv2.GaussianBlur(tex, (0, 0), sig) if sig > 0.05 else tex
            out[:, pos == p] = layer[:, pos == p]
        frames.append(out)
    return frames


def levels_of(frames):
    sampler = scale.TileSampler.for_size(frames[0].shape[:2])
    return [np.stack(lev) for lev in zip(*(sampler.sample(f) for f in frames))]


@pytest.mark.parametrize("sigma_step", [1.5, 3.0, 6.0])
def test_blur_step_is_measured_from_the_frames(sigma_step):
    """The estimate (a blur-disk diameter, 4 sigma) is within 35 % of the rendered step."""
    step, info = scale.blur_step_px(levels_of(stack_with_step(sigma_step)))
    assert step is not None, info
    assert 0.65 * 4 * sigma_step < step < 1.35 * 4 * sigma_step, (step, info)


def test_blur_step_survives_noise_and_an_exposure_change():
    frames = stack_with_step(3.0, seed=1)
    rng = np.random.default_rng(2)
    frames = [np.clip(f * (1.0 + 0.3 * (i % 2)) + rng.normal(0, 0.01, f.shape), 0, None).astype(np.float32)
              for i, f in enumerate(frames)]
    step, info = scale.blur_step_px(levels_of(frames))
    assert step is not None and 0.6 * 12 < step < 1.4 * 12, (step, info)


def test_no_texture_no_step():
    flat = [np.full((480, 640, 3), 0.4, np.float32) for _ in range(5)]
    step, info = scale.blur_step_px(levels_of(flat))
    assert step is None and all(lev["used"] == 0 for lev in info["levels"])
    assert scale.working_factor(step, (3072, 4080)) == 1.0  # unknown: the frames' own size


def test_the_rule_hand_cases():
    s, l = scale.STEP_MIN_PX, scale.SIDE_MIN_PX
    assert scale.working_factor(10 * s, (l * 3, l * 4)) == pytest.approx(4.0)  # the size floor binds
    assert scale.working_factor(2 * s, (l * 3, l * 4)) == pytest.approx(2.0)  # the step binds
    assert scale.working_factor(1.1 * s, (l * 3, l * 4)) == 1.0  # below K_MIN: not worth resampling
    assert scale.working_factor(10 * s, (l // 2, l)) == 1.0  # frames already at the floor
    assert "k = min(blur step" in scale.rule_text()


class Counting:
    """Frames as functions that count their decodes."""

    def __init__(self, frames):
        self.frames, self.calls = frames, [0] * len(frames)

    def sources(self):
        def make(i):
            def decode():
                self.calls[i] += 1
                return self.frames[i]
            return decode
        return [make(i) for i in range(len(self.frames))]


def test_frames_are_decoded_once_and_reduced_as_they_come():
    big = [np.repeat(np.repeat(f, 4, 0), 4, 1) for f in stack_with_step(1.5, h=300, w=400, s=5)]  # 1600 x 1200
    src = Counting(big)
    method = FocusMethod()
    frames, geometry, size0, natives, choice = fitted_frames(src.sources(), method)
    assert src.calls == [1] * 5 and size0 == (1200, 1600) and natives is None
    k = choice["factor"]
    assert k > 1 and frames[0].shape[:2] == (round(1200 / k), round(1600 / k))
    assert geometry["crop_xywh"] == [0, 0, 1600, 1200] and choice["blur_step_px"] > 0


def test_a_small_step_decodes_again_at_the_size_it_needs():
    """The frames are kept reduced by the size floor's factor while the step is unknown; a step too small for that
    reduction decodes them again (and says so)."""
    frames = stack_with_step(0.4, h=1200, w=2100, s=4)  # 2100 px: kept at 1/2 while the step is measured
    src = Counting(frames)
    out, _, _, natives, choice = fitted_frames(src.sources(), FocusMethod(), native=True)
    assert choice["factor"] < 2 and choice.get("decoded_twice") and src.calls == [2] * 4
    assert out[0].shape[:2] == (round(1200 / choice["factor"]), round(2100 / choice["factor"]))
    assert natives[0].dtype == np.float16 and natives[0].shape == (1200, 2100, 3)


def test_fixed_sizes_keep_the_old_path():
    frames = stack_with_step(2.0, h=240, w=320, s=4)
    for max_side, wh in ((0, (320, 240)), (160, (160, 120))):
        res = depth_from_frames(frames, 1.0 / np.linspace(2.0, 0.5, 4), FocusMethod(max_side=max_side))
        assert res.working_size == wh and "working_resolution" not in (res.info or {})
    res = depth_from_frames(frames, 1.0 / np.linspace(2.0, 0.5, 4), FocusMethod())
    assert res.working_size == (320, 240)  # below the floor: not reduced, and the summary says why
    assert res.info["working_resolution"]["factor"] == 1.0 and res.frame_hw == (240, 320)
