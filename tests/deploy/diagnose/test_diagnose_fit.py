"""The diagnosis's fitted settings on rendered captures whose truth is known (aat_deploy.diagnose.fitters), the
reduced-resolution twins they search with (aat_deploy.diagnose.binned), and the corrected focus a user gets.

Captures: 2 procedural scenes through a thin-lens simulator of the RF50 on a 192 x 128 sensor, frames as float
TIFFs (no RAW development), with one effect the twin lacks."""

import copy
import dataclasses
import json

import numpy as np
import pytest
import torch
from conftest import ROOT

from tests.deploy_fixtures import build_tiny_dff

RF50 = "lenses/canon_rf50mm_f1.8.json"
FOCUS_M = 1.0 / np.linspace(1.7, 0.2, 7)


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    from aat_deploy.lens.io import load_lens

    tmp = tmp_path_factory.mktemp("fit")
    lens = load_lens(RF50)
    lens = dataclasses.replace(lens, sensor=dataclasses.replace(lens.sensor, width_px=192, height_px=128))
    model = build_tiny_dff(tmp / "tiny.onnx", {"aat.lens_name": lens.name, "aat.sensor_mm": [36.0, 24.0],
                                               "aat.sensor_px": [192, 128], "aat.pixel_um": 187.5,
                                               "aat.focus_range_m": [0.5, 10.0]}, sharpness=20.0)
    return tmp, lens, model


def render_set(world, name: str, effects, n: int = 2, focus_m=FOCUS_M, frame_format: str = "tiff"):
    """Capture folders rendered with the thin-lens simulator plus `effects` (a list, or per scene s: effects(s)),
    frames as float TIFFs or DNGs (`frame_format`: a RAW the runtime develops); their CaptureData and a renderer."""
    from aat_deploy.capture.virtual import write_capture
    from aat_deploy.diagnose.inputs import load_capture_data
    from aat_deploy.diagnose.lookup import find_lens
    from aat_deploy.diagnose.session import make_renderer
    from aat_deploy.infer.model import DfFModel
    from training.data.scenes import SceneConfig, procedural_scene
    from training.render.layered import LayeredConfig
    from training.render.simulator import Simulator
    from training.render.sources import thin_lens_source

    tmp, lens, model_path = world
    folders = []
    for s in range(n):
        out = tmp / name / f"scene{s}"
        if not out.exists():
            sim = Simulator(lens, None, effects(s) if callable(effects) else effects, LayeredConfig(cell_px=64),
                            thin_lens_source(lens))
            rgb, depth = procedural_scene(SceneConfig(height=128, width=192, near_m=0.6, far_m=5.0),
                                          np.random.default_rng(10 + s))
            rgb = np.ascontiguousarray(rgb.transpose(2, 0, 1))
            st = sim.render_stack(torch.from_numpy(rgb), torch.from_numpy(depth), focus_m,
                                  rng=np.random.default_rng(s))
            write_capture(out, st.frames.numpy(), st.focus_reported_m, lens, depth, rgb, {}, frame_format=frame_format)
        folders.append(out)
    m = DfFModel(model_path, threads=2)
    twins = make_renderer(m, find_lens(m, RF50)[0], None, torch_free=True)
    return [load_capture_data(f, m) for f in folders], twins


def state_for(caps, twins, chain=(), n_boot=20):
    from aat_deploy.diagnose import fitters as F
    from aat_deploy.render import effects as fx

    full = [F.fit_curves(twins.render(c, c.aif_linear, list(chain), seed=i), 1) for i, c in enumerate(caps)]
    return F.FitState(twins, caps, [c.aif_linear for c in caps], list(chain), fx.make, factor=1, n_boot=n_boot,
                      full_curves=full)


@pytest.mark.filterwarnings("ignore:.*real-ray focus table")
def test_distance_scale_error_is_fitted_as_a_scale(world):
    """Reported distance = 1.08 x true (the issue's encoder error): the fit names the scale family, its value, and
    corrects every frame's focus to within 0.03 D."""
    from aat_deploy.diagnose import fitters as F
    from aat_deploy.render import effects as fx

    caps, twins = render_set(world, "scale", [fx.make("focus_metadata", bias_d=0.0, scale=1.08)])
    assert np.allclose(caps[0].focus_m, 1.08 * FOCUS_M)
    r = F.fit_focus_metadata(state_for(caps, twins))
    f = r.report["focus_fit"]
    assert f["family"] == "scale" and r.params["scale"] == pytest.approx(1.08, abs=0.03)
    for c in r.report["corrected_focus"]:
        assert np.abs(1 / np.array(c["corrected_m"]) - 1 / FOCUS_M).max() < 0.03
        assert c["files"] == [f"frame_{i:02d}.tif" for i in range(len(FOCUS_M))]


@pytest.mark.filterwarnings("ignore:.*real-ray focus table")
def test_true_focus_reports_no_metadata_error(world):
    from aat_deploy.diagnose import fitters as F

    caps, twins = render_set(world, "clean", [])
    r = F.fit_focus_metadata(state_for(caps, twins))
    assert r.params is None and r.report["focus_fit"]["family"] == "none"


@pytest.mark.filterwarnings("ignore:.*real-ray focus table")
def test_sensor_tilt_is_fitted_continuously(world):
    """A 1.3 deg tilt about the vertical axis (not one of the old candidates 0.5 / 1.0): the fit finds its axis,
    sign and size."""
    from aat_deploy.diagnose import fitters as F
    from aat_deploy.render import effects as fx

    caps, twins = render_set(world, "tilt", [fx.make("sensor_tilt", tilt_x_deg=1.3, tilt_y_deg=0.0)])
    r = F.fit_sensor_tilt(state_for(caps, twins))
    assert r.params is not None
    assert r.params["tilt_x_deg"] == pytest.approx(1.3, abs=0.35) and abs(r.params["tilt_y_deg"]) < 0.35
    lo, hi = r.report["shift_fit"]["params_ci"]["tilt_x_deg"]
    assert lo < hi and hi > 0.6


@pytest.mark.filterwarnings("ignore:.*real-ray focus table")
def test_noise_and_breathing_are_fitted_continuously(world):
    """Full well 700 e- (between the old candidates): fitted within a factor 1.6; focus breathing as rendered:
    coefficient near 1; a clean set: no noise, no breathing."""
    from aat_deploy.diagnose import fitters as F
    from aat_deploy.render import effects as fx

    caps, twins = render_set(world, "noise", [fx.make("noise", full_well_e=700.0)])
    r = F.fit_noise(state_for(caps, twins))
    assert r.params is not None and 700 / 1.6 < r.params["full_well_e"] < 700 * 1.6
    caps, twins = render_set(world, "breathing", [fx.make("focus_breathing")])
    r = F.fit_breathing(state_for(caps, twins))
    assert r.params is not None and r.params["coefficient"] == pytest.approx(1.0, abs=0.25)
    caps, twins = render_set(world, "clean", [])
    st = state_for(caps, twins)
    assert F.fit_breathing(st).params is None
    assert F.fit_noise(st).params is None or F.fit_noise(st).params["full_well_e"] > 20000


@pytest.mark.filterwarnings("ignore:.*real-ray focus table")
def test_exposure_and_misalignment_are_fitted_per_capture(world):
    """Per-frame gains (up to 12 %) and shifts (up to 2 px), different in every capture: every capture's gains
    within 2 % and its shifts within 0.4 px of the ones rendered."""
    from aat_deploy.diagnose import fitters as F
    from aat_deploy.render import effects as fx

    gains = {"scene0": [1.0, 1.09, 0.93, 1.05, 0.97, 1.12, 0.9], "scene1": [0.95, 1.0, 1.1, 0.92, 1.04, 1.0, 1.08]}
    caps, twins = render_set(world, "exposure", lambda s: [fx.make("exposure", gains=gains[f"scene{s}"])])
    r = F.fit_exposure(state_for(caps, twins))
    for c in caps:
        got, want = np.array(r.params["by_capture"][c.name]), np.array(gains[c.name])
        assert np.abs(np.log(got / want) - np.median(np.log(got / want))).max() < 0.02
    warps = {"scene0": [0, 0, 1, 1.5, -0.5, 1, -1, 2, 1, 0.5, 0.5, 1, 2, 1, 1, -1.5, 0, 1, 0, -1, 1],
             "scene1": [1, 1, 1, 0, 0, 1, -2, 0.5, 1, 1, -1, 1, 0, 1.5, 1, 0.5, 0.5, 1, -1, -1, 1]}
    caps, twins = render_set(world, "misaligned",
                             lambda s: [fx.make("misalignment", by_capture={"": warps[f"scene{s}"]})])
    r = F.fit_misalignment(state_for(caps, twins))
    for c in caps:
        got = np.array(r.params["by_capture"][c.name]).reshape(-1, 3)
        want = np.array(warps[c.name], float).reshape(-1, 3)
        assert np.abs(got[:, :2] - want[:, :2]).max() < 0.4 and np.abs(got[:, 2] - 1).max() < 0.01
    clean, twins = render_set(world, "clean", [])
    st = state_for(clean, twins)
    assert F.fit_exposure(st).params is None and F.fit_misalignment(st).params is None


@pytest.mark.filterwarnings("ignore:.*real-ray focus table")
def test_lens_tolerance_is_fitted_through_the_table(world):
    """The cemented doublet decentred 0.4 mm along x (the shipped RF50 table): the fit finds a perturbation whose
    focal-surface change at the frame's edges is the rendered one's within 30 %."""
    from aat_deploy.diagnose import fitters as F
    from aat_deploy.render import effects as fx
    from aat_deploy.render.effects.lens_tolerance import table_name

    table = str(ROOT / "models" / table_name(world[1]))

    def make(name, **kw):
        return fx.make(name, **({"table": table} if name == "lens_tolerance" else {}), **kw)

    truth = make("lens_tolerance", element=1.0, decentre_x_mm=0.4)
    caps, twins = render_set(world, "decentred", [truth])
    st = state_for(caps, twins)
    st.make = make
    r = F.fit_lens_tolerance(st)
    assert r.params is not None
    ctx = twins.context()
    x, y, f = np.array([-1.0, 1.0, 0.0, 0.0]), np.array([0.0, 0.0, -1.0, 1.0]), np.full(4, 1.5)
    want = truth.sensor_shift_mm(ctx)(x, y, f)
    got = make("lens_tolerance", **r.params).sensor_shift_mm(ctx)(x, y, f)
    assert np.abs(got - want).max() < 0.3 * np.abs(want).max()


@pytest.mark.filterwarnings("ignore:.*real-ray focus table")
def test_binned_twin_is_the_binned_full_twin(world):
    """A twin rendered on the 2x2-binned sensor is close to the full-resolution twin binned (pixels), and its
    PSF source keeps the kernels' energy with cells half as wide."""
    from aat_deploy.diagnose.binned import BinnedSource, bin_depth, bin_frames, binned_capture
    from aat_deploy.render.sources import GaussianSource

    caps, twins = render_set(world, "clean", [])
    c = caps[0]
    full = twins.linear(c, c.aif_linear, [])
    tb, cb = twins.binned(2), binned_capture(c, 2)
    half = tb.linear(cb, cb.aif_linear, [])
    assert half.shape == (len(FOCUS_M), 3, 64, 96)
    ref = bin_frames(full, 2)
    assert np.abs(half - ref).mean() < 0.02 * ref.mean()
    src = BinnedSource(GaussianSource(twins.lens), 2)
    k0, s0 = GaussianSource(twins.lens)(np.zeros(3), np.zeros(3), np.array([1.0, 2.0, 0.7]), np.full(3, 1.0))
    k, s = src(np.zeros(3), np.zeros(3), np.array([1.0, 2.0, 0.7]), np.full(3, 1.0))
    assert np.allclose(k.sum((1, 2)), k0.sum((1, 2)), rtol=1e-5)
    assert np.allclose(s, np.maximum(s0 / 2, 1.0))
    # depth: the block's mean inverse depth over its known pixels
    d = np.array([[1.0, 2.0], [np.nan, 4.0]], np.float32)
    assert bin_depth(d, 2)[0, 0] == pytest.approx(3 / (1 + 0.5 + 0.25))
    assert np.isnan(bin_depth(np.full((2, 2), np.nan, np.float32), 2)[0, 0])


@pytest.mark.filterwarnings("ignore:.*real-ray focus table")
def test_diagnosis_writes_corrected_capture_json(world, tmp_path):
    """aat-diagnose on a set whose reported focus is 1.08 x the true one: focus_metadata named as a scale error,
    corrected focus distances in diagnosis.json and report.md, and drop-in capture.json files that the capture
    reader accepts and that bring the focus within 0.03 D of the truth."""
    from aat_deploy.capture.folder import read_capture
    from aat_deploy.cli.diagnose import main
    from aat_deploy.render import effects as fx

    render_set(world, "scale", [fx.make("focus_metadata", bias_d=0.0, scale=1.08)])  # as the first test
    tmp, _, model = world
    out = tmp_path / "diag"
    assert main([str(tmp / "scale"), "--model", str(model), "--lens", str(ROOT / RF50), "--out", str(out),
                 "--effects", "focus_metadata,noise,sensor_tilt", "-q"]) == 0
    d = json.loads((out / "diagnosis.json").read_text())
    assert d["focus"]["family"] == "scale" and d["focus"]["named"]
    assert "Focus metadata" in (out / "report.md").read_text()
    for c in d["focus"]["corrected_focus"]:
        side = out / "corrected_focus" / c["capture"] / "capture.json"
        frames = json.loads(side.read_text())["frames"]
        assert [f["file"] for f in frames] == c["files"]
        # the capture folder with the sidecar copied in reads the corrected focus
        folder = tmp / "scale" / c["capture"]
        copy = tmp_path / c["capture"]
        copy.mkdir()
        for f in folder.iterdir():
            (copy / f.name).write_bytes(f.read_bytes())
        (copy / "capture.json").write_text(side.read_text())
        got = sorted(f.focus_m for f in read_capture(copy).frames)
        assert np.abs(1 / np.array(got) - 1 / FOCUS_M).max() < 0.03


def test_focus_brightness_is_fitted_and_not_invented(world):
    """Frames darker the nearer they are focused (the working f-number, focus_brightness at coefficient 1): the
    fitted coefficient within 0.15 of 1; captures without it get none."""
    from aat_deploy.diagnose import fitters as F
    from aat_deploy.render import effects as fx

    caps, twins = render_set(world, "brightness", [fx.make("focus_brightness")])
    r = F.fit_focus_brightness(state_for(caps, twins))
    assert r.params is not None and r.params["coefficient"] == pytest.approx(1.0, abs=0.15)
    clean, twins = render_set(world, "clean", [])
    assert F.fit_focus_brightness(state_for(clean, twins)).params is None


@pytest.mark.filterwarnings("ignore:.*real-ray focus table")
def test_noisy_raw_captures_keep_per_frame_focus_off_its_bounds(world):
    """Issue 32 on rendered captures like the shipped sample: DNGs the runtime develops, strong noise (1000 e-) and
    vignetting the first round's twin lacks, reported distances 1.15 x the true ones (every truth well inside the
    +-0.4 D search bound). The robust fit keeps every per-frame estimate off its bound and within 0.05 D of the
    truth, none left out for sitting on its bound; the plain fit on the same sweep (no floors, gains or weights)
    puts one on its bound, which `focusfit.LEAVE_OUT_ON_BOUND` then leaves out (no estimate left on a bound)."""
    from aat_deploy.diagnose import fitters as F
    from aat_deploy.diagnose import focusfit as ff
    from aat_deploy.render import effects as fx

    caps, twins = render_set(world, "noisy_raw", [fx.make("noise", full_well_e=1000.0), fx.make("vignetting"),
                                                  fx.make("focus_metadata", bias_d=0.0, scale=1.15)],
                             frame_format="dng")
    true_d = 1 / FOCUS_M
    assert np.abs(1 / caps[0].focus_m - true_d).max() < 0.3  # the truth inside the bound
    state = state_for(caps, twins)
    f = F.fit_focus_metadata(state).report["focus_fit"]
    assert not np.any(f["frames_on_bound"]) and not np.any(f["frames_left_out_on_bound"])
    est = np.array(f["frame_focus_d"], np.float64)  # null (NaN): a noise-dominated frame has no estimate
    dom = np.array(f["frames_noise_dominated"], bool)
    assert np.array_equal(np.isnan(est), dom)
    assert dom.sum() < dom.size / 2  # most frames keep an estimate
    assert np.nanmax(np.abs(est - true_d)) < 0.05
    plain = ff.fit_metadata(F.focus_sweep(state), n_boot=5)
    assert plain.bound_left_out.any() and not plain.on_bound.any()


@pytest.mark.filterwarnings("ignore:.*real-ray focus table")
@pytest.mark.parametrize("again", [False, True])
def test_full_well_is_fitted_again_on_the_reanchored_sweep_only_when_asked(world, monkeypatch, again):
    """`fitters.FULL_WELL_ON_FINAL_SWEEP` (a probe's setting, off; `focus_start_invariance --mode refit`), on the noisy
    RAW set above, whose first estimates move far enough to be re-anchored: off, the full well is fitted once, on the
    first sweep, and that fit's ratio is applied to the re-anchored sweep; on, it is fitted again on the re-anchored
    sweep, and the focus fit and the report's `noise` use that second fit."""
    from aat_deploy.diagnose import fitters as F
    from aat_deploy.diagnose import focusrobust
    from aat_deploy.render import effects as fx

    caps, twins = render_set(world, "noisy_raw", [fx.make("noise", full_well_e=1000.0), fx.make("vignetting"),
                                                  fx.make("focus_metadata", bias_d=0.0, scale=1.15)],
                             frame_format="dng")
    calls, fits = [], []
    real_fw, real_fit = F.full_well_on_floor, focusrobust.fit_robust

    def spy_fw(d, fw0):
        out = real_fw(d, fw0)
        calls.append((d, fw0, out[0]))
        return out

    def spy_fit(d, **kw):
        fits.append(d)
        return real_fit(d, **kw)

    monkeypatch.setattr(F, "full_well_on_floor", spy_fw)
    monkeypatch.setattr(focusrobust, "fit_robust", spy_fit)
    monkeypatch.setattr(F, "FULL_WELL_ON_FINAL_SWEEP", again)
    f = F.fit_focus_metadata(state_for(caps, twins)).report["focus_fit"]
    assert f["robust"].get("reanchored_d")  # the estimates moved: the correction was anchored at them too
    assert len(fits) == 1 and fits[0].floor_c is not None
    assert len(calls) == (2 if again else 1)
    first, last = calls[0][0], calls[-1][0]
    # the first sweep (anchored at the reported focus only) differs from the one fitted (re-anchored)
    assert np.abs(first.signal_c - fits[0].signal_c).max() > 0
    if again:  # the second fit is on the very sweep the focus fit uses
        assert np.array_equal(last.signal_c, fits[0].signal_c)
    fw0, fw = calls[-1][1], calls[-1][2]
    ratio = 0.0 if fw is None else fw0 / fw
    assert np.allclose(fits[0].floor_c, last.with_full_well(ratio).floor_c)
    assert f["focus_twin"]["noise"]["fitted_full_well_e"] == fw


@pytest.mark.filterwarnings("ignore:.*real-ray focus table")
def test_full_well_by_photon_transfer_replaces_the_fit_against_the_floor(world, monkeypatch):
    """`fitters.FULL_WELL_BY_PHOTON_TRANSFER` on the noisy RAW set above (rendered at 1000 e-): the focus twin's full
    well is the one measured on the captures' mosaics (within 10 % of 1000 e-), `full_well_on_floor` is never
    called, and the focus fit's floor is that full well's; off, the fit against the floor decides as before."""
    from aat_deploy.diagnose import fitters as F
    from aat_deploy.diagnose import focusfit as ff
    from aat_deploy.render import effects as fx

    caps, twins = render_set(world, "noisy_raw", [fx.make("noise", full_well_e=1000.0), fx.make("vignetting"),
                                                  fx.make("focus_metadata", bias_d=0.0, scale=1.15)],
                             frame_format="dng")

    calls, ratios = [], []
    real_ratio = ff.SweepData.with_full_well
    monkeypatch.setattr(F, "full_well_on_floor", lambda d, fw0: calls.append(fw0) or (None, {}))
    monkeypatch.setattr(ff.SweepData, "with_full_well", lambda d, r: ratios.append(r) or real_ratio(d, r))
    monkeypatch.setattr(F, "FULL_WELL_BY_PHOTON_TRANSFER", True)
    measured, _ = F.full_well_by_photon_transfer(caps)
    assert measured == pytest.approx(1000.0, rel=0.1)
    fw0 = float(fx.make("noise").params["full_well_e"])
    noise = F.fit_focus_metadata(state_for(caps, twins)).report["focus_fit"]["focus_twin"]["noise"]
    assert calls == [] and noise["fitted_full_well_e"] == measured
    assert noise["photon_transfer"]["full_well_e"] == pytest.approx(measured, rel=0.01)
    assert ratios and set(ratios) == {fw0 / measured}  # every sweep the fit saw carries the measured floor
    monkeypatch.setattr(F, "FULL_WELL_BY_PHOTON_TRANSFER", False)
    ratios.clear()
    noise = F.fit_focus_metadata(state_for(caps, twins)).report["focus_fit"]["focus_twin"]["noise"]
    assert calls == [fw0] and noise["fitted_full_well_e"] is None and "photon_transfer" not in noise
    assert set(ratios) == {0.0}  # the (stubbed) fit against the floor found none: no noise


@pytest.mark.filterwarnings("ignore:.*real-ray focus table")
def test_binning_correction_at_the_twins_own_focus_renders_no_new_optics(world):
    """The binning correction's anchors at the twin's own focus (`anchors.anchor_deltas`) reuse the twin's cached
    optics: given as the twin has it, not as the inverse of its diopters (which differs in the last bit and cost
    one more full-resolution optical render per round, issue 32's speed). Anchors elsewhere still render."""
    from aat_deploy.diagnose import anchors as A

    caps, twins = render_set(world, "clean", [])
    state = state_for(caps, twins)
    before = twins.renders
    own = [twins.true_focus(c, [], seed=i) for i, c in enumerate(caps)]
    deltas = A.anchor_deltas(state, [], own)
    assert twins.renders == before
    for (d, delta), f in zip(deltas, own):
        assert np.array_equal(d, 1.0 / f) and delta.shape[1] == len(f) and np.isfinite(delta).all()
    A.anchor_deltas(state, [], [f * 1.01 for f in own])
    assert twins.renders == before + len(caps)


@pytest.mark.filterwarnings("ignore:.*real-ray focus table")
def test_floor_at_the_capture_exposure_divides_the_measured_full_well_by_the_twins_exposure(world, monkeypatch):
    """`fitters.FLOOR_AT_CAPTURE_EXPOSURE` with the full well measured by photon transfer (issue 32, docs/diagnosis.md,
    "The focus twin's misfit in the weak frames, noise off on both sides"): `capture_exposure` reads every capture's
    brightness over its twin's (unchanged when the capture is brighter, since the twin's percentile match follows it;
    1.3 x when the twin comes out 1.3 x too dim), and the focus fit's floor is the twin's at the measured full well
    times that ratio, per capture; off, the measured full well alone, as before."""
    from aat_deploy.diagnose import fitters as F
    from aat_deploy.diagnose import focusfit as ff
    from aat_deploy.render import effects as fx

    caps, twins = render_set(world, "noisy_raw", [fx.make("noise", full_well_e=1000.0), fx.make("vignetting"),
                                                  fx.make("focus_metadata", bias_d=0.0, scale=1.15)],
                             frame_format="dng")
    state = state_for(caps, twins)
    k, rep = F.capture_exposure(state)
    assert k.shape == (len(caps),) and np.all(np.isfinite(k) & (k > 0)), k
    assert rep["exposure_ratio"] == [round(float(x), 4) for x in k]
    # the captures' frames 1.2 x brighter: the twin's percentile match follows them, so the ratio stays (it measures
    # what the match gets wrong, not the exposure)
    bright = copy.copy(state)
    bright.caps_b = [dataclasses.replace(c, frames=c.frames * 1.2) for c in state.caps_b]
    assert np.allclose(F.capture_exposure(bright)[0], k, rtol=1e-4)
    # a twin whose percentile match leaves it 1.3 x too dim: scale its linear frames, not the capture's
    real_linear = type(state.tb).linear
    monkeypatch.setattr(type(state.tb), "linear", lambda self, *a, **kw: real_linear(self, *a, **kw) / 1.3)
    k13, _ = F.capture_exposure(state)
    assert np.allclose(k13, 1.3 * k, rtol=1e-3)
    monkeypatch.setattr(type(state.tb), "linear", real_linear)

    ratios = []
    real_ratio = ff.SweepData.with_full_well
    monkeypatch.setattr(ff.SweepData, "with_full_well", lambda d, r: ratios.append(r) or real_ratio(d, r))
    monkeypatch.setattr(F, "FULL_WELL_BY_PHOTON_TRANSFER", True)
    monkeypatch.setattr(F, "FLOOR_AT_CAPTURE_EXPOSURE", True)
    exposure = np.array([1.25, 0.8])
    monkeypatch.setattr(F, "capture_exposure", lambda st: (exposure, {"exposure_ratio": exposure.tolist()}))
    measured, _ = F.full_well_by_photon_transfer(caps)
    fw0 = float(fx.make("noise").params["full_well_e"])
    noise = F.fit_focus_metadata(state_for(caps, twins)).report["focus_fit"]["focus_twin"]["noise"]
    assert noise["fitted_full_well_e"] == measured
    assert noise["capture_exposure"]["effective_full_well_e"] == [round(measured * x) for x in exposure]
    assert ratios and all(np.allclose(r, fw0 / (measured * exposure)) for r in ratios)
    monkeypatch.setattr(F, "FLOOR_AT_CAPTURE_EXPOSURE", False)
    ratios.clear()
    noise = F.fit_focus_metadata(state_for(caps, twins)).report["focus_fit"]["focus_twin"]["noise"]
    assert "capture_exposure" not in noise and ratios and set(ratios) == {fw0 / measured}
