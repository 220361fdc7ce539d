"""Float agreement between kernels: the relative differences the `numerics` tests and the export parity checks bound,
measured under the settings .ci/run uses, next to the tolerance each check states.

    OMP_WAIT_POLICY=PASSIVE python -m benchmarks.bench_numerics

Each setting runs in its own interpreter (thread counts and kernel choices are fixed at import): the default, the
CI's second pass (OMP_NUM_THREADS=1, torch's deterministic algorithms) and, on an AVX-512 CPU, that pass with torch's
and oneDNN's AVX2 kernels. A row is the largest relative difference (`tests/conftest.py:rel_err`, max |a - b| over
the stated scale) of one comparison; prints a markdown table. About 30 s per setting on 2 cores.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = {
    "default": {},
    "1 thread, deterministic": {"OMP_NUM_THREADS": "1", "AAT_TEST_NUMERICS": "strict"},
    "+ AVX2 kernels": {"OMP_NUM_THREADS": "1", "AAT_TEST_NUMERICS": "strict", "ATEN_CPU_CAPABILITY": "avx2",
                       "ONEDNN_MAX_CPU_ISA": "AVX2"},
}


def measure() -> dict[str, tuple[float, float]]:
    """{comparison: (relative difference, the tolerance the code or test states)} in this interpreter."""
    import numpy as np
    import torch

    torch.set_num_threads(1)  # as tests/conftest.py
    if os.environ.get("AAT_TEST_NUMERICS") == "strict":
        torch.use_deterministic_algorithms(True)
    from aat_deploy.lens.io import load_lens
    from aat_deploy.psf.kernel import KernelSpec
    from training.nets import export as dff_export
    from training.nets.model import build_model
    from training.nets.warm_start import load_onnx_weights
    from training.psf import export as psf_export
    from training.psf.surrogates import RotPSF
    from training.render.sources import thin_lens_source

    for d in ("tests", "tests/training/nets", "tests/deploy/diagnose"):  # the tolerances the tests state
        sys.path.insert(0, str(ROOT / d))
    from conftest import rel_err
    from test_twin import THIN_F32
    from test_warm_start import FOLD_REL

    from aat_deploy.render.sources import GaussianSource

    out: dict[str, tuple[float, float]] = {}
    ef50, rf50 = load_lens(ROOT / "lenses/canon_ef50mm_f1.8.json"), load_lens(ROOT / "lenses/canon_rf50mm_f1.8.json")
    with tempfile.TemporaryDirectory() as tmp:
        # the DFVNet of tests/training/nets/test_warm_start.py: trained-like batch norms, exported, folded into torch
        torch.manual_seed(0)
        src = build_model("dfvnet", "small").eval()
        with torch.no_grad():
            for m in src.modules():
                if isinstance(m, torch.nn.modules.batchnorm._BatchNorm):
                    m.running_mean.uniform_(-0.2, 0.2)
                    m.running_var.uniform_(0.5, 2.0)
                    m.weight.uniform_(0.5, 1.5)
                    m.bias.uniform_(-0.1, 0.1)
        md = dff_export.dff_metadata(src, ef50, simulator="aat", effects=[], focus_range_m=(0.5, 10),
                                     stack_range=(2, 16), config_hash="bench")
        path = Path(tmp) / "dfv.onnx"
        dff_export.export_dff_onnx(src, path, md, check_shapes=[(1, 3, 32, 32)])
        g = torch.Generator().manual_seed(1)
        stack, focus = torch.rand(1, 4, 3, 64, 64, generator=g), torch.tensor([[0.5, 1.0, 2.0, 5.0]])
        dst = build_model("dfvnet", "small")
        load_onnx_weights(dst, path)
        with torch.no_grad():
            out["DFVNet depth, folded batch norms vs torch"] = (rel_err(dst.eval()(stack, focus)[0],
                                                                        src(stack, focus)[0]), FOLD_REL)
        shapes = [(1, 5, 64, 96), (2, 3, 32, 32), (1, 9, 96, 64)]
        out["DFVNet, onnxruntime vs torch (parity)"] = (dff_export.parity(src, path, shapes), dff_export.PARITY_TOL)
        torch.manual_seed(3)
        aif = build_model("aifnet", "small").eval()
        path = Path(tmp) / "aif.onnx"
        md = dff_export.dff_metadata(aif, ef50, simulator="aat", effects=[], focus_range_m=(0.5, 10),
                                     stack_range=(2, 16), config_hash="bench")
        dff_export.export_dff_onnx(aif, path, md, check_shapes=[(1, 3, 32, 32)])
        out["AiFNet, onnxruntime vs torch (parity)"] = (dff_export.parity(aif, path, shapes), dff_export.PARITY_TOL)
        # an untrained RotPSF, as tests/training/psf/test_surrogates.py exports it
        torch.manual_seed(0)
        rot = RotPSF(rf50, KernelSpec.for_lens(rf50), 0.3, 20)
        path = Path(tmp) / "psf.onnx"
        psf_export.export_psf_onnx(rot, rf50, path, check=False)
        out["RotPSF, onnxruntime vs torch (parity)"] = (psf_export.parity(psf_export._Wrapper(rot.eval()), path),
                                                        psf_export.PARITY_TOL)
    # the thin-lens Gaussian (field-invariant) in float32, torch and numpy, against float64: 400,000 queries, most
    # near focus, where the blur is a difference of nearly equal image distances
    rng = np.random.default_rng(5)
    thin, numpy_thin = thin_lens_source(rf50), GaussianSource(rf50)
    worst = {"torch": 0.0, "numpy": 0.0}
    for _ in range(20):
        n = 20_000
        f = 1 / rng.uniform(0.05, 3.3, n)
        d = np.clip(f * (1 + rng.uniform(-0.3, 0.3, n) * rng.uniform(0, 1, n) ** 3), 0.2, 100.0)
        x = y = np.zeros(n)
        q64 = torch.from_numpy(np.stack([x, y, d, f], -1).astype(np.float32).astype(np.float64))
        k64 = thin.model(q64).numpy()
        peak = k64.max((1, 2))
        for name, k in (("torch", thin(x, y, d, f)[0].numpy()), ("numpy", numpy_thin(x, y, d, f)[0])):
            worst[name] = max(worst[name], float((np.abs(k - k64).max((1, 2)) / peak).max()))
    for name, v in worst.items():
        out[f"thin-lens kernel, {name} float32 vs float64 (of its peak)"] = (v, THIN_F32)
    return out


def main() -> None:
    if "--measure" in sys.argv:
        print(json.dumps(measure()))
        return
    settings = dict(SETTINGS)
    if "avx512f" not in Path("/proc/cpuinfo").read_text():
        del settings["+ AVX2 kernels"]  # this CPU runs AVX2 kernels already
    cols: dict[str, dict] = {}
    for name, env in settings.items():
        res = subprocess.run([sys.executable, __file__, "--measure"], capture_output=True, text=True,
                             env={**os.environ, "PYTHONPATH": str(ROOT), **env}, cwd=ROOT)
        if res.returncode != 0:
            raise SystemExit(f"{name}: {res.stderr[-2000:]}")
        cols[name] = json.loads(res.stdout.strip().splitlines()[-1])
        print(f"done {name}", flush=True)
    rows = list(next(iter(cols.values())))
    print("\n### Relative differences between kernels (max |a - b| / scale)\n")
    print("| comparison | " + " | ".join(cols) + " | tolerance |")
    print("|---|" + "---|" * (len(cols) + 1))
    for r in rows:
        vals = " | ".join(f"{cols[c][r][0]:.1e}" for c in cols)
        print(f"| {r} | {vals} | {next(iter(cols.values()))[r][1]:.0e} |")


if __name__ == "__main__":
    main()
