"""The runtime never imports torch: run it in a fresh interpreter where `import torch` raises."""

from __future__ import annotations

import json

from conftest import ROOT
from deploy_fixtures import run_without_torch, tiny_model_path, write_dng_capture


def test_blocker_works(tmp_path):
    r = run_without_torch("import torch\n", tmp_path)
    assert r.returncode != 0 and "forbidden" in r.stderr


def test_runtime_runs_without_torch(tmp_path, tmp_path_factory):
    model = tiny_model_path(tmp_path_factory)
    cap = write_dng_capture(tmp_path / "cap", [0.7, 1.0, 1.6, 3.0])
    out = tmp_path / "out"
    r = run_without_torch(f"""
        import json, pkgutil, importlib, sys
        import aat_deploy
        for m in pkgutil.walk_packages(aat_deploy.__path__, "aat_deploy."):
            importlib.import_module(m.name)
        from aat_deploy.cli import infer, capture, view
        rc = infer.main([{str(cap)!r}, "--model", {str(model)!r}, "--out", {str(out)!r}, "--threads", "1", "-q"])
        assert rc == 0, rc
        rc = capture.main(["inspect", {str(cap)!r}, "--json"])
        assert rc == 0, rc
        print(json.dumps({{"torch_loaded": any(k == "torch" or k.startswith("torch.") for k in sys.modules)}}))
    """, tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert json.loads(r.stdout.strip().splitlines()[-1]) == {"torch_loaded": False}
    assert (out / "depth_m.npy").is_file() and (out / "recording.rrd").is_file()


def test_twin_renderer_and_effects_run_without_torch(tmp_path):
    """The torch-free twin renderer (`aat_deploy.diagnose.twin`, `aat_deploy.render`) and the effects registry it shares with training: every
    effect module imports, every numpy-capable effect renders a crop through the shipped PSF surrogate, and
    `chromatic` (ray tracing) says it needs torch."""
    r = run_without_torch(f"""
        import json, sys, warnings
        import numpy as np
        warnings.simplefilter("error")  # the shipped surrogate carries its focus table: no paraxial fallback
        from aat_deploy.render.optical import optical_stack
        from aat_deploy.render.sources import GaussianSource, OnnxSource
        from aat_deploy.lens.io import load_lens
        from aat_deploy.render import effects as fx
        lens = load_lens({str(ROOT / "lenses/canon_rf50mm_f1.8.json")!r})
        src = OnnxSource({str(ROOT / "models/psf_rf50.onnx")!r}, lens, threads=1)
        ctx = fx.SimContext(lens, (640, 960), (0, 0), src, src.focus_table(), src.exit_pupil_z_mm())
        rng = np.random.default_rng(0)
        rgb, depth = rng.random((3, 32, 48), dtype=np.float32), np.full((32, 48), 1.5, np.float32)
        effects = fx.parse("aberrations,vignetting,sensor_tilt,focus_breathing,noise,focus_metadata")
        focus = fx.twin_focus(effects, [1.0, 2.0], ctx, rng)
        frames = optical_stack(effects, GaussianSource(lens), rgb, depth, focus, ctx)
        frames = [fx.post_frame(effects, f, float(d), ctx, rng) for f, d in zip(frames, focus)]
        assert all(f.shape == (3, 32, 48) and np.isfinite(f).all() for f in frames)
        assert fx.parse("chromatic")[0].needs_torch
        print(json.dumps({{"effects": fx.names(),
                           "torch_loaded": any(k == "torch" or k.startswith("torch.") for k in sys.modules)}}))
    """, tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["torch_loaded"] is False and "chromatic" in out["effects"] and "sensor_tilt" in out["effects"]


def test_focus_method_runs_without_torch(tmp_path):
    """`aat-infer --method focus`: thin-lens, with --psf (the map stamped in the surrogate) and with --lens (the map
    stored next to the lens file) without torch; a lens without a map is a one-line error saying how to make it."""
    import shutil

    cap = write_dng_capture(tmp_path / "cap", [0.6, 0.8, 1.1, 1.6, 3.0])
    lens_copy = tmp_path / "lenses" / "rf50_copy.json"
    lens_copy.parent.mkdir()
    shutil.copy(ROOT / "lenses/canon_rf50mm_f1.8.json", lens_copy)
    r = run_without_torch(f"""
        import json, sys
        from aat_deploy.cli import infer
        cap = {str(cap)!r}
        rcs = [infer.main([cap, "--method", "focus", "--out", {str(tmp_path / "o1")!r}, "-q"]),
               infer.main([cap, "--method", "focus", "--psf", {str(ROOT / "models/psf_rf50.onnx")!r},
                           "--out", {str(tmp_path / "o2")!r}, "-q"]),
               infer.main([cap, "--method", "focus", "--lens", {str(ROOT / "lenses/canon_rf50mm_f1.8.json")!r},
                           "--out", {str(tmp_path / "o3")!r}, "-q"]),
               infer.main([cap, "--method", "focus", "--lens", {str(lens_copy)!r}, "--out", {str(tmp_path / "o4")!r}])]
        print(json.dumps({{"rcs": rcs,
                           "torch_loaded": any(k == "torch" or k.startswith("torch.") for k in sys.modules)}}))
    """, tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out == {"rcs": [0, 0, 0, 2], "torch_loaded": False}
    err = [ln for ln in r.stderr.splitlines() if ln.startswith("aat-infer: error")]
    assert len(err) == 1 and "rf50_copy.json" in err[0] and "torch is not installed" in err[0] \
        and "aat-lens focus-map" in err[0]
    for o in ("o1", "o2", "o3"):
        assert (tmp_path / o / "depth_m.npy").is_file() and (tmp_path / o / "confidence.npy").is_file()
    assert json.loads((tmp_path / "o3" / "summary.json").read_text())["model"]["mapping"] == "aberration_aware"
