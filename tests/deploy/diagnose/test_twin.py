"""Torch-free twins (`aat_deploy.diagnose.twin`) against the torch simulator: PSF sources, the layered renderer, every
numpy-capable effect, the surrogate's focus metadata, and a twin of a tiny virtual capture rendered in an
interpreter where torch cannot be imported."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch
from conftest import ROOT, rel_err
from deploy_fixtures import build_tiny_dff, run_without_torch

from aat_deploy.lens.io import load_lens, save_lens
from aat_deploy.optics.field import field_of
from aat_deploy.optics.paraxial import paraxial_data
from aat_deploy.render import effects as fx
from aat_deploy.render.layered import LayeredConfig, render_layered
from aat_deploy.render.optical import optical_stack
from aat_deploy.render.sources import GaussianSource, OnnxSource, UnitEnergy
from training.psf.geometry import focus_table
from training.render.layered import render_layered as render_layered_torch
from training.render.simulator import Simulator
from training.render.sources import OnnxPSF, thin_lens_source

LENS = load_lens(ROOT / "lenses/canon_rf50mm_f1.8.json")
SENSOR = (LENS.sensor.height_px, LENS.sensor.width_px)
ONNX = OnnxPSF(ROOT / "models/psf_rf50.onnx", LENS, threads=1)
CFG = LayeredConfig(cell_px=16)
pytestmark = pytest.mark.numerics  # numpy vs torch renderers and sources
# Relative agreement (max |difference| / max |value|, `conftest.rel_err`) of float32 frames and kernels.
# With the surrogate both sides get the same onnxruntime kernels and differ only by the renderers' float32 FFTs and
# sums (~log2(N) eps ~ 1e-6; 5e-7 seen). The thin-lens Gaussian is evaluated in float32 by each side: its blur near
# focus is a difference of nearly equal image distances (~50 mm, up to ~8 ulps apart: 4e-4 px), so each kernel is
# within ~1e-4 of its peak of the float64 one (the worst of 400,000 queries near focus: benchmarks/bench_numerics.py)
# and the two within twice that, as are frames built of them.
TOL = 1e-5
THIN_F32 = 2e-4  # a float32 thin-lens kernel vs float64, relative to its peak
TOL_THIN = 2 * THIN_F32


def _scene(h=32, w=64, seed=0):
    rng = np.random.default_rng(seed)
    rgb = rng.random((3, h, w), dtype=np.float32)
    depth = (1 / rng.uniform(1 / 3.0, 1 / 0.5, (h, w))).astype(np.float32)
    depth[:, : w // 3] = 0.6  # a near slab: a depth edge
    return rgb, depth


def test_sources_match_torch():
    rng = np.random.default_rng(0)
    n = 500
    x, y = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
    d, f = 1 / rng.uniform(0.05, 3.3, n), 1 / rng.uniform(0.05, 3.3, n)
    d[:50] = f[:50]  # in focus: the thin-lens blur is a difference of nearly equal image distances
    thin_t, thin_n = thin_lens_source(LENS), GaussianSource(LENS)
    kt, st = (t.numpy() for t in thin_t(x, y, d, f))
    kn, sn = thin_n(x, y, d, f)
    assert kn.dtype == np.float32 and kn.shape == kt.shape == (n, 11, 11)
    # float32 evaluation on both sides, each to float32 rounding of the blur (torch may fuse multiply-adds, and
    # differently on another CPU): both near the float64 kernels, so near each other
    q64 = torch.from_numpy(np.stack([x, y, d, f], -1).astype(np.float32).astype(np.float64))  # the same inputs
    k64, s64 = thin_t.model(q64).numpy(), thin_t.model.scale(q64[:, 2], q64[:, 3]).numpy()
    peak_rel = lambda a, b: float((np.abs(a - b).max((1, 2)) / b.max((1, 2))).max())  # noqa: E731
    assert peak_rel(kt, k64) < THIN_F32 and peak_rel(kn, k64) < THIN_F32 and peak_rel(kt, kn) < TOL_THIN
    # the cell size (blur + margin) / (k - 1) >= 1: the blur's ~4e-4 px are <= 4e-5 of it (6e-6 seen)
    assert np.abs(st / s64 - 1).max() < 4e-5 and np.abs(sn / s64 - 1).max() < 4e-5
    # exact: both sides call the same float64 numpy function (aat_deploy.optics.thin_lens.thin_lens_blur_px)
    assert thin_n.k == thin_t.k and np.array_equal(thin_n.scale(d, f), thin_t.scale(d, f))
    assert np.array_equal(thin_n.blur_px(d, f), thin_t.blur_px(d, f))
    # the surrogate: the same onnxruntime session underneath, numpy out
    kt, st = ONNX(x, y, d, f)
    kn, sn = ONNX.numpy(x, y, d, f)
    assert isinstance(kn, np.ndarray) and np.array_equal(kt.numpy(), kn) and np.array_equal(st.numpy(), sn)
    # unit energy, numpy or torch kernels
    un, ut = UnitEnergy(ONNX.numpy)(x, y, d, f)[0], UnitEnergy(ONNX)(x, y, d, f)[0].numpy()
    # kernel / its sum, the same division on both sides (numpy and torch sums may add in another order)
    assert np.allclose(un.sum((1, 2)), 1, rtol=1e-5, atol=0) and rel_err(un, ut) < 1e-6


def test_surrogate_carries_the_traced_focus_table():
    table = ONNX.numpy.focus_table()
    ref = focus_table(LENS)
    # the same trace: equal to float64 rounding (the last bits of a trace depend on the CPU's math library)
    assert np.array_equal(table.diopters, ref.diopters)
    np.testing.assert_allclose(table.sensor_z_mm, ref.sensor_z_mm, rtol=1e-13, atol=0)
    assert ONNX.numpy.exit_pupil_z_mm() == paraxial_data(LENS).exit_pupil_z_mm


def _tilt(x, y, f):
    from aat_deploy.render.effects.sensor_tilt import tilted_focus_m

    return tilted_focus_m(LENS, x, y, f, 2.0, -1.0)


@pytest.mark.parametrize("source, focus_at, occlusion, origin", [
    ("surrogate", None, False, (0, 0)), ("surrogate", _tilt, False, (300, 500)), ("surrogate", None, True, (0, 0)),
    ("thin", None, False, (300, 500)), ("thin", _tilt, True, (0, 0))])
def test_layered_matches_torch(source, focus_at, occlusion, origin):
    rgb, depth = _scene()
    st, sn = {"surrogate": (UnitEnergy(ONNX), UnitEnergy(ONNX.numpy)),
              "thin": (thin_lens_source(LENS), GaussianSource(LENS))}[source]
    cfg = dataclasses.replace(CFG, occlusion=occlusion)

    def field(r, c):
        return field_of(r, c, SENSOR, origin)

    for f in (0.7, 2.0):
        a = render_layered_torch(torch.from_numpy(rgb), torch.from_numpy(depth), f, st, field, cfg,
                                 focus_at=focus_at).numpy()
        b = render_layered(rgb, depth, f, sn, field, cfg, focus_at=focus_at)
        assert b.dtype == np.float32 and b.shape == a.shape
        assert rel_err(a, b) < (TOL if source == "surrogate" else TOL_THIN), f


def _numpy_context(origin):
    src = ONNX.numpy
    return fx.SimContext(LENS, SENSOR, origin, src, src.focus_table(), src.exit_pupil_z_mm())


def _same_noise(a, a0, b, b0) -> None:
    """Noisy stacks a, b over noiseless a0, b0 (two renderers): the same noise statistics. Draws are not compared
    one by one: a Poisson draw whose mean differs by float32 rounding may take another rejection-sampling path and
    shift the generator's stream from there on."""
    na, nb = np.asarray(a, np.float64) - a0, np.asarray(b, np.float64) - b0
    assert abs(na.std() / nb.std() - 1) < 0.05 and abs(na.mean() - nb.mean()) < 0.05 * na.std()


@pytest.mark.parametrize("names", [
    ["aberrations"], ["aberrations", "vignetting"], ["aberrations", "sensor_tilt:tilt_x_deg=1.5"],
    ["aberrations", "focus_breathing"], ["vignetting", "noise:full_well_e=3000"], ["sensor_tilt:tilt_y_deg=-1"]])
def test_effects_match_torch(names):
    rgb, depth = _scene(seed=1)
    effects, focus, origin = fx.parse(names), np.array([0.6, 2.5]), (20, 30)
    sim = Simulator(LENS, ONNX, effects, CFG)
    ctx_t = sim.context(origin)
    a0 = sim.optical(torch.from_numpy(rgb), torch.from_numpy(depth), focus, ctx_t)
    a = sim.post(a0, focus, ctx_t, np.random.default_rng(3)).numpy()
    ctx, rng = _numpy_context(origin), np.random.default_rng(3)
    b0 = optical_stack(effects, GaussianSource(LENS), rgb, depth, focus, ctx, CFG)
    b = np.stack([fx.post_frame(effects, fr, float(f), ctx, rng) for fr, f in zip(b0, focus)])
    assert b.dtype == np.float32 and b.shape == a.shape
    tol = TOL if "aberrations" in names else TOL_THIN  # without it both render with their thin-lens Gaussians
    assert rel_err(a0.numpy(), b0) < tol
    if any(e.name == "noise" for e in effects):
        _same_noise(a, a0.numpy(), b, b0)
    else:
        assert rel_err(a, b) < tol


# --- a tiny virtual capture, its twin rendered without torch and with torch ---------------------------------------

TWIN_EFFECTS = ["", "vignetting", "noise:full_well_e=3000", "sensor_tilt:tilt_x_deg=-0.4",
                "focus_breathing", "focus_metadata:bias_d=0.1:quantise=nikon"]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """The RF50 on a 96x64 sensor with an (untrained, small) RotPSF surrogate exported for it, a classical-DfF
    model 'trained' with the AAT simulator for it, and one virtual capture with ground truth."""
    from aat_deploy.capture.virtual import write_capture
    from aat_deploy.psf.kernel import KernelSpec
    from training.data.scenes import SceneConfig, procedural_scene
    from training.psf.export import export_psf_onnx
    from training.psf.surrogates import RotPSF

    tmp = tmp_path_factory.mktemp("twin")
    lens = dataclasses.replace(LENS, sensor=dataclasses.replace(LENS.sensor, width_px=96, height_px=64))
    save_lens(lens, tmp / "lens.json")
    torch.manual_seed(0)
    export_psf_onnx(RotPSF(lens, KernelSpec(11, 4.0), 0.3, 20.0, width=32, hidden=2), lens, tmp / "psf.onnx")
    model = build_tiny_dff(tmp / "tiny.onnx", {"aat.simulator": "aat", "aat.lens_name": lens.name,
                                               "aat.sensor_mm": [36.0, 24.0], "aat.sensor_px": [96, 64],
                                               "aat.pixel_um": 375.0, "aat.focus_range_m": [0.5, 10.0]})
    rgb, depth = procedural_scene(SceneConfig(height=64, width=96, near_m=0.8, far_m=3.0), np.random.default_rng(0))
    rgb = np.ascontiguousarray(rgb.transpose(2, 0, 1))
    focus = 1.0 / np.linspace(1.6, 0.25, 5)
    sim = Simulator(lens, None, [], LayeredConfig(cell_px=32), thin_lens_source(lens))
    st = sim.render_stack(torch.from_numpy(rgb), torch.from_numpy(depth), focus, rng=np.random.default_rng(0))
    write_capture(tmp / "cap", st.frames.numpy(), st.focus_reported_m, lens, depth, rgb, {})
    np.save(tmp / "aif.npy", rgb)
    return tmp, lens, model


def test_export_metadata_and_stamping(tiny, tmp_path):
    import onnx

    from aat_deploy.psf.surrogate import PSFSurrogate
    from training.psf.export import stamp_optics_metadata

    tmp, lens, _ = tiny
    meta = PSFSurrogate(tmp / "psf.onnx").meta
    ref = focus_table(lens)
    assert json.loads(meta["aat.focus_table_diopters"]) == ref.diopters.tolist()
    assert json.loads(meta["aat.focus_table_sensor_z_mm"]) == ref.sensor_z_mm.tolist()
    # an older export without the keys: no table (the renderer falls back to the paraxial one, with a warning)
    m = onnx.load(str(tmp / "psf.onnx"))
    keep = [p for p in m.metadata_props if "focus_table" not in p.key and "exit_pupil" not in p.key]
    del m.metadata_props[:]
    m.metadata_props.extend(keep)
    old = tmp_path / "old.onnx"
    onnx.save(m, str(old))
    assert OnnxSource(old, lens).focus_table() is None
    with pytest.raises(ValueError, match="lens hash"):
        stamp_optics_metadata(old, LENS)  # the 960x640 sensor is another prescription
    stamp_optics_metadata(old, lens)
    t = OnnxSource(old, lens).focus_table()
    assert np.array_equal(t.sensor_z_mm, ref.sensor_z_mm)
    assert OnnxSource(old, lens).exit_pupil_z_mm() == paraxial_data(lens).exit_pupil_z_mm


def test_paraxial_fallback_warns(tiny, tmp_path):
    import onnx

    from aat_deploy.diagnose.twin import TwinRenderer
    from aat_deploy.infer.model import DfFModel

    tmp, lens, model = tiny
    m = onnx.load(str(tmp / "psf.onnx"))
    keep = [p for p in m.metadata_props if "focus_table" not in p.key]
    del m.metadata_props[:]
    m.metadata_props.extend(keep)
    onnx.save(m, str(tmp_path / "old.onnx"))
    with pytest.warns(UserWarning, match="paraxial"):
        twins = TwinRenderer(DfFModel(model), lens, tmp_path / "old.onnx", threads=1)
    table, ref = twins.context().focus_table(), focus_table(lens)
    n = min(len(table.diopters), len(ref.diopters))
    assert np.abs(table.sensor_z_mm[:n] - ref.sensor_z_mm[:n]).max() < 0.5  # mm: spherical aberration apart


def test_what_needs_torch(tiny):
    from aat_deploy.diagnose.twin import TwinRenderer
    from aat_deploy.infer.model import DfFModel

    tmp, lens, model = tiny
    twins = TwinRenderer(DfFModel(model), lens, tmp / "psf.onnx", cell_px=32, threads=1)
    assert [e.name for e in twins.base] == ["aberrations"]
    rgb, depth = _scene(16, 16)
    with pytest.raises(fx.NeedsTorch, match=r"'chromatic' needs the training package \(torch\)"):
        twins.optical(fx.parse("chromatic"), rgb, depth, np.array([1.0]), twins.context())
    assert twins.why_torch(fx.parse("aberrations,vignetting,noise,sensor_tilt,focus_breathing,focus_metadata")) is None
    with pytest.warns(UserWarning, match="paraxial"):
        bare = TwinRenderer(DfFModel(model), lens, None)
    assert "no PSF surrogate" in bare.why_torch(fx.parse("aberrations"))
    assert bare.why_torch(fx.parse("noise,sensor_tilt,focus_breathing,focus_metadata")) is None


def test_tiny_twin_without_torch_equals_torch(tiny, tmp_path):
    from aat_deploy.diagnose.inputs import load_capture_data
    from aat_deploy.infer.model import DfFModel
    from training.render.torch_twin import TorchTwinRenderer

    tmp, lens, model_path = tiny
    r = run_without_torch(f"""
        import sys, numpy as np
        from aat_deploy.diagnose.inputs import load_capture_data
        from aat_deploy.infer.model import DfFModel
        from aat_deploy.diagnose.twin import TwinRenderer
        from aat_deploy.lens.io import load_lens
        from aat_deploy.render import effects as fx
        model = DfFModel({str(model_path)!r}, threads=1)
        twins = TwinRenderer(model, load_lens({str(tmp / "lens.json")!r}), {str(tmp / "psf.onnx")!r}, cell_px=32,
                             threads=1)
        cap = load_capture_data({str(tmp / "cap")!r}, model)
        aif = np.load({str(tmp / "aif.npy")!r})
        out = {{s or "base": twins.render(cap, aif, fx.parse(s), seed=5) for s in {TWIN_EFFECTS!r}}}
        np.savez({str(tmp_path / "twins.npz")!r}, **out)
        try:
            twins.render(cap, aif, fx.parse("chromatic"))
            raise SystemExit("chromatic rendered without torch")
        except fx.NeedsTorch as e:
            assert "needs the training package (torch)" in str(e), e
        assert not any(k == "torch" or k.startswith("torch.") for k in sys.modules), "torch was imported"
        print("renders", twins.renders)
    """, tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stdout.split()[-1] == "4"  # noise and focus breathing reuse the base stack
    got = np.load(tmp_path / "twins.npz")
    model = DfFModel(model_path, threads=1)
    cap = load_capture_data(tmp / "cap", model)
    aif = np.load(tmp / "aif.npy")
    ref = TorchTwinRenderer(model, lens, OnnxPSF(tmp / "psf.onnx", lens, threads=1), cell_px=32, torch_only=True)
    for s in TWIN_EFFECTS:
        a, b = ref.render(cap, aif, fx.parse(s), seed=5), got[s or "base"]
        assert a.shape == b.shape == (5, 3, 64, 96)
        if s.startswith("noise"):
            _same_noise(a, ref.render(cap, aif, [], seed=5), b, got["base"])
        else:
            assert rel_err(a, b) < TOL, (s, rel_err(a, b))
    # the training side's renderer picks numpy by itself for these, the torch simulator for chromatic: the same
    # numpy code and onnxruntime session settings as in the subprocess, bit for bit
    auto = TorchTwinRenderer(model, lens, OnnxPSF(tmp / "psf.onnx", lens, threads=1), cell_px=32)
    assert np.array_equal(auto.render(cap, aif, [], seed=5), got["base"])
    chroma = auto.render(cap, aif, fx.parse("chromatic:n_rays=32"))
    assert chroma.shape == (5, 3, 64, 96) and np.isfinite(chroma).all() and auto.renders == 2
