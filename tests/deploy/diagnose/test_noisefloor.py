"""The noise's expected focus measure in the binned focus sweep (aat_deploy.diagnose.noisefloor; issue 32, scene
2038): against the focus curves of frames that were really given noise and a RAW development at full resolution
and then binned, as a capture is."""

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from aat_deploy.diagnose import noisefloor as nf
from aat_deploy.diagnose.binned import bin_frames
from aat_deploy.diagnose.compare import focus_curves
from aat_deploy.infer.normalise import normalise_scale, normalise_stack, scaled
from aat_deploy.render.effects import make

GRID, B, FULL_WELL, READ = (3, 4), 4, 2000.0, 3.0


def frames(blurs=(0, 1, 2, 4, 8), h=240, w=360, seed=1) -> np.ndarray:
    """(S, 3, H, W) linear frames of one textured scene, sharp to strongly blurred (the last ones: mostly noise
    once noise is added)."""
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.random((h, w, 3)).astype(np.float32), (0, 0), 1.0)
    base = 0.05 + 0.4 * (base - base.min()) / (base.max() - base.min())
    return np.stack([(cv2.GaussianBlur(base, (0, 0), s) if s else base).transpose(2, 0, 1) for s in blurs])


def test_developed_noise_keeps_more_of_its_energy_when_binned():
    """Demosaicking spreads a photosite's draw over its neighbours: binned 4 x 4 it keeps 1.5-3 x the Laplacian
    energy of independent noise; without a development the factor is 1."""
    noise = make("noise", full_well_e=FULL_WELL, read_noise_e=READ)
    f = nf.developed_factor([noise, make("raw_pipeline", demosaic="bilinear")], B)
    assert np.all(f > 1.4) and np.all(f < 3.2), f
    assert f[1] < f[0] and f[1] < f[2]  # green has twice the photosites
    assert np.all(nf.developed_factor([noise], B) == 1.0)


@pytest.mark.parametrize("develop", [False, True])
def test_expected_floor_matches_noisy_frames_binned(develop):
    """The binned renderer's noiseless frames with the expected floor (scaled for the development, the noiseless
    development's change of the measure added under it, as the sweep's binning correction does) match the focus
    curves of frames given noise (and developed) at full resolution and binned: within 0.06 log in rms and in every
    frame's mean, where a noise draw at the binned sensor (b^2 the full well: independent noise) is off by more than
    0.3 log in the frames that show mostly noise, and the noiseless curves by more still."""
    rng = np.random.default_rng(3)
    x = frames()
    noise = make("noise", full_well_e=FULL_WELL, read_noise_e=READ)
    chain = [noise] + ([make("raw_pipeline", demosaic="bilinear")] if develop else [])
    ctx = SimpleNamespace(origin=(0, 0))

    def dev(f):
        return chain[1].sensor(f, ctx, rng) if develop else f

    noisy = np.stack([dev(noise.sensor(f, ctx, rng)) for f in x])
    truth = focus_curves(normalise_stack(bin_frames(np.clip(noisy, 0, None), B)), GRID).mean(-1)  # (R, S)
    lin = np.clip(bin_frames(x, B), 0, None)  # what the binned renderer gives without noise
    scale = float(normalise_scale(lin))
    signal = focus_curves(scaled(lin, scale), GRID)  # (R, S, C)
    floor = nf.floor(lin, scale, noise.binned(B), nf.developed_factor(chain, B), GRID)
    full = focus_curves(normalise_stack(bin_frames(np.clip(np.stack([dev(f) for f in x]), 0, None), B)), GRID).mean(-1)
    expected = nf.compose(signal + (full - signal.mean(-1))[..., None], floor)
    d = expected - truth
    assert np.sqrt(np.mean(d ** 2)) < 0.06 and np.all(np.abs(d.mean(0)) < 0.06), d.mean(0)
    drawn = focus_curves(normalise_stack(np.clip(np.stack([noise.binned(B).sensor(f, ctx, rng) for f in lin]), 0,
                                                 None)), GRID).mean(-1)
    if develop:
        assert (drawn - truth).mean(0)[-1] < -0.3
    assert (signal.mean(-1) - truth).mean(0)[-1] < -1.0


def test_applies_only_where_the_noise_is_last_but_a_development():
    noise, raw = make("noise"), make("raw_pipeline")
    assert nf.applies([noise]) and nf.applies([make("vignetting"), noise, raw])
    assert not nf.applies([raw]) and not nf.applies([])
    assert not nf.applies([noise, make("phone_jpeg")])
    assert [e.name for e in nf.quiet([make("vignetting"), noise, raw])] == ["vignetting", "raw_pipeline"]


@pytest.mark.parametrize("true_fw", [4000.0, 12000.0])
def test_full_well_is_fitted_against_the_expected_floor(true_fw):
    """`fitters.full_well_on_floor`: a sweep made with the expected floor of 8000 e- and captures whose floor is
    that of another full well (every frame's focus free): the full well found to 10 %; a capture without noise
    gives none."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from test_focusrobust import NOISY_REPORTED_D, noisy_far_sweep

    from aat_deploy.diagnose import fitters

    true = NOISY_REPORTED_D[None].copy()
    data = noisy_far_sweep(true, true, floor_misfit=8000.0 / true_fw, floor_log=-3.5)
    fw, rep = fitters.full_well_on_floor(data, 8000.0)
    assert fw == pytest.approx(true_fw, rel=0.1), rep
    quiet = noisy_far_sweep(true, true, floor_misfit=0.0, floor_log=-3.5)
    assert fitters.full_well_on_floor(quiet, 8000.0)[0] is None
