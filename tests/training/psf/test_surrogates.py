"""PSF surrogates: baselines against hand-computed cases, rotation against ray tracing, fitting, ONNX export."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
import torch
from conftest import LENSES, ROOT, assert_close

from aat_deploy.lens.io import load_lens
from aat_deploy.optics.paraxial import paraxial_data
from aat_deploy.optics.thin_lens import thin_lens_blur_px
from aat_deploy.psf.kernel import KernelSpec
from training.psf.dataset import PSFDataConfig, build_psf_dataset, eval_grid, to_tensors
from training.psf.fit import FitConfig, fit
from training.psf.raytrace import raytrace_psfs
from training.psf.surrogates import GaussianPSF, GridPSF, PaperMLP, RotPSF, n_params

RF50 = load_lens(LENSES / "canon_rf50mm_f1.8.json")
SPEC = KernelSpec.for_lens(RF50)


def test_thin_lens_blur_hand_computed():
    p = paraxial_data(RF50)
    f, epd = p.efl_mm, p.entrance_pupil_mm
    # Focus 2 m from the sensor: lens-sensor distance v solves v + u = 2000, 1/u + 1/v = 1/f.
    v = (2000 - math.sqrt(2000**2 - 4 * 2000 * f)) / 2
    u_obj = 1000 - v  # object 1 m from the sensor
    v_obj = 1 / (1 / f - 1 / u_obj)
    by_hand = epd * (v_obj - v) / v_obj / RF50.sensor.pixel_mm
    assert thin_lens_blur_px(RF50, 1.0, 2.0) == pytest.approx(by_hand, rel=1e-9)
    assert thin_lens_blur_px(RF50, 2.0, 2.0) == pytest.approx(0.0, abs=1e-9)
    m = GaussianPSF(RF50, SPEC, 0.3, 20)
    q = torch.tensor([[0.0, 0.0, 1.0, 2.0]], dtype=torch.float64)
    assert float(m.blur_px(q[:, 2], q[:, 3])) == pytest.approx(by_hand, rel=1e-9)


def test_gaussian_psf_shape_and_energy_by_hand():
    m = GaussianPSF(RF50, SPEC, 0.3, 20)
    q = torch.tensor([[0.3, 0.2, 2.0, 2.0], [0.3, 0.2, 1.2, 2.0]], dtype=torch.float64)
    k = m(q)
    assert torch.allclose(k, torch.flip(k, (1,))) and torch.allclose(k, k.transpose(1, 2))
    assert float(k[0].sum()) == pytest.approx(1.0, rel=1e-6)  # in focus: all energy inside
    assert float(k[0, 5, 5]) > 0.5  # a point (only the splat tent spreads it)
    s = float(m.scale(q[1:, 2], q[1:, 3]))
    coc = thin_lens_blur_px(RF50, 1.2, 2.0)
    sigma_cells = math.sqrt((coc / 4 / s) ** 2 + 1 / 6)  # disk second moment + tent, in cells
    assert float(k[1, 5, 6] / k[1, 5, 5]) == pytest.approx(math.exp(-1 / (2 * sigma_cells**2)), rel=1e-9)
    inside = math.erf(5.5 / (sigma_cells * math.sqrt(2))) ** 2  # continuous estimate of the window's share
    assert float(k[1].sum()) == pytest.approx(inside, rel=0.02)
    assert float(k[1].sum()) < 0.999  # tails outside the window are lost, not renormalised


def test_paper_mlp_has_the_published_size():
    assert n_params(PaperMLP(RF50, SPEC, 0.3, 20)) == 295_545


def test_rotation_of_axis_psfs_reproduces_ray_traced_field_psfs():
    """Feed RotPSF the ray-traced +y-axis kernels; rotated into place they must match direct tracing."""
    rng = np.random.default_rng(0)
    n = 48
    x, y = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
    f = 1 / rng.uniform(0.3, 2.0, n)
    d = 1 / np.clip(1 / f + rng.normal(0, 0.2, n), 0.05, 3.3)
    model = RotPSF(RF50, SPEC, 0.3, 20)
    r, cos_phi, sin_phi = model.field_polar(torch.tensor(x), torch.tensor(y))
    ay = r.numpy() * RF50.sensor.half_diagonal_mm / (RF50.sensor.height_mm / 2)
    axis = raytrace_psfs(RF50, 0 * ay, ay, d, f, SPEC, n_rays=8192, seed=1, oversample=2).kernels
    direct = raytrace_psfs(RF50, x, y, d, f, SPEC, n_rays=8192, seed=2).kernels
    again = raytrace_psfs(RF50, x, y, d, f, SPEC, n_rays=8192, seed=3).kernels  # noise floor
    from training.psf.splat import downsample2

    rotated = downsample2(model.rotate(axis, cos_phi.float(), sin_phi.float()))
    err = (rotated - direct).abs().sum((1, 2)).mean()
    noise = (again - direct).abs().sum((1, 2)).mean()
    # Bicubic resampling on the half-cell grid costs about 2 % of the energy in l1 (comparable to the ray noise
    # of a 2048-ray trace); anything wrong with the rotation costs far more.
    assert err < 0.025 and err < 5 * noise
    # Without rotation (or rotated the wrong way) the error is far larger: the test can fail.
    wrong = downsample2(model.rotate(axis, cos_phi.float(), -sin_phi.float()))
    assert (wrong - direct).abs().sum((1, 2)).mean() > 3 * err


@pytest.mark.numerics
def test_grid_interpolation_is_exact_at_nodes():
    axes = GridPSF.axes(0.3, 20, 3, 4, 2, 3)
    F, D, Y, X = np.meshgrid(*axes, indexing="ij")
    tab = torch.rand(*F.shape, 11, 11)
    g = GridPSF(RF50, SPEC, 0.3, 20, tab)
    q = torch.tensor(np.stack([X.ravel(), Y.ravel(), D.ravel(), F.ravel()], -1), dtype=torch.float32)
    # float32 fractional indices land within a few ulps of the nodes: the neighbours' weights stay below ~1e-6
    assert_close(g(q), tab.view(-1, 11, 11), 1e-5)


def test_eval_grid_is_the_papers():
    g = eval_grid(RF50)
    assert g["x"].size == 20 * 40 * 8 * 10
    inv_f = np.unique(np.round(1 / g["focus_m"], 9))
    assert len(inv_f) == 20 and np.allclose(np.diff(inv_f), np.diff(inv_f)[0])  # even in diopters


def test_dataset_cache_and_fit_resume(tmp_path):
    cfg = PSFDataConfig(layout="axis", n=300, n_rays=256, seed=5)
    data = build_psf_dataset(RF50, cfg, tmp_path, compiled=False, chunk=128, progress=False)
    assert data["kernels"].shape == (300, 23, 23)
    again = build_psf_dataset(RF50, cfg, tmp_path, compiled=False, progress=False)  # from the cache
    assert np.array_equal(again["kernels"], data["kernels"])
    t = to_tensors(data)
    model = RotPSF(RF50, SPEC, 0.3, 20)
    ckpt = tmp_path / "rot.pt"
    vq = torch.stack([t["x"][:64], t["y"][:64], t["depth_m"][:64], t["focus_m"][:64]], -1)
    from training.psf.splat import downsample2

    val = (vq, downsample2(t["kernels"][:64]))
    h1 = fit(model, t, FitConfig(minutes=0.05, eval_every_s=1.0), ckpt=ckpt, val=val, progress=False).history
    steps1 = torch.load(ckpt, weights_only=False)["step"]
    h2 = fit(RotPSF(RF50, SPEC, 0.3, 20), t, FitConfig(minutes=0.1, eval_every_s=1.0), ckpt=ckpt, val=val,
             progress=False).history
    st = torch.load(ckpt, weights_only=False)
    assert st["step"] > steps1 and st["elapsed"] >= 0.1 * 60
    assert h2[: len(h1)] == h1  # history carried over
    assert h2[-1]["l1"] < h1[0]["l1"]  # it learns


@pytest.mark.numerics
def test_onnx_export_parity_metadata_and_torch_free_query(tmp_path):
    from training.psf.export import export_psf_onnx

    torch.manual_seed(0)
    model = RotPSF(RF50, SPEC, 0.3, 20)
    out = tmp_path / "psf.onnx"
    md = export_psf_onnx(model, RF50, out, extra_metadata={"fit": "test"})
    assert md["aat.lens_hash"] == RF50.prescription_hash() and md["aat.kernel_size"] == "11"
    with pytest.raises(FileExistsError):
        export_psf_onnx(model, RF50, out)
    code = f"""
import sys, numpy as np
from aat_deploy.psf.surrogate import PSFSurrogate
m = PSFSurrogate({str(out)!r})
rng = np.random.default_rng(0)
n = 100_000
k, s = m.query(rng.uniform(-1, 1, n), rng.uniform(-1, 1, n), 1 / rng.uniform(0.05, 3.3, n), 1.5)
assert k.shape == (n, 11, 11) and s.shape == (n,) and np.isfinite(k).all()
k0, _ = m.query(0.0, 0.0, 1.0, 1.5)  # exactly on the axis
assert np.isfinite(k0).all() and k0.sum() > 0.5
assert 'torch' not in sys.modules, 'the runtime imported torch'
try:
    m.query(0.0, 0.0, 50.0, 1.5)
    raise SystemExit('range not checked')
except ValueError as e:
    assert 'outside the model' in str(e)
print(float(k[:10].sum()), m.meta['aat.fit'])
"""
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert res.returncode == 0, res.stderr
    # The same queries through torch.
    rng = np.random.default_rng(0)
    n = 100_000
    q = np.stack([rng.uniform(-1, 1, n), rng.uniform(-1, 1, n), 1 / rng.uniform(0.05, 3.3, n),
                  np.full(n, 1.5)], -1).astype(np.float32)[:10]
    with torch.no_grad():
        ref = float(model(torch.from_numpy(q)).sum())
    ort_sum, fit_name = res.stdout.split()
    # a sum of energies (a sigmoid each; the softmax shapes sum to 1): float32 rounding of ~1e-6 relative
    assert float(ort_sum) == pytest.approx(ref, rel=1e-5) and fit_name == "test"


def test_psf_show_cli(tmp_path):
    from training.cli.psf import main

    png = tmp_path / "psfs.png"
    assert main(["show", str(LENSES / "canon_rf50mm_f1.8.json"), "--focus-m", "1.5", "--depths-m", "1.2,1.5,2",
                 "--fields-deg", "0,12,23.5", "--png", str(png), "--rays", "1024", "--model", "none"]) == 0
    assert png.read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(SystemExit, match="exists"):  # never overwrite without --force
        main(["show", str(LENSES / "canon_rf50mm_f1.8.json"), "--focus-m", "1.5", "--depths-m", "1.2",
              "--fields-deg", "0", "--png", str(png)])
    assert main(["show", str(LENSES / "canon_rf50mm_f1.8.json"), "--focus-m", "1.5", "--depths-m", "1.2",
                 "--fields-deg", "0", "--png", str(tmp_path / "b.png"), "--model", str(tmp_path / "no.onnx")]) == 2
