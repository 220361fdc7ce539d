"""Export a PSF surrogate to ONNX with the metadata a runtime needs to use it correctly."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import torch
from torch import nn

from aat_deploy.io.atomic import atomic_file
from aat_deploy.lens.schema import Lens
from aat_deploy.optics.paraxial import paraxial_data
from aat_deploy.render.sources import EXIT_PUPIL_KEY, TABLE_KEYS
from training.psf.geometry import DEFAULT_NEAR_M, focus_table_reaching
from training.psf.surrogates import PSFModel

INPUTS_DOC = ("query (B, 4) float32 = x, y, depth_m, focus_m. x, y: normalised upright image position in [-1, 1] "
              "(x right, y up, +-1 = sensor edges), naming the object direction tan(theta) = x W/2 / EFL, "
              "y H/2 / EFL. depth_m, focus_m: metres from the sensor plane.")
OUTPUTS_DOC = ("kernels (B, k, k) float32: energy per cell (sum = energy reaching the sensor inside the window, "
               "not renormalised), row 0 at the top, centre cell on the chief ray's hit. scale (B,) float32: cell "
               "size in sensor pixels (>= 1; resample to pixels before convolving).")


class _Wrapper(nn.Module):
    def __init__(self, model: PSFModel):
        super().__init__()
        self.model = model

    def forward(self, query: torch.Tensor):
        return self.model(query), self.model.scale(query[:, 2], query[:, 3])


def metadata(model: PSFModel, lens: Lens, extra: dict | None = None) -> dict[str, str]:
    sen = lens.sensor
    md = {
        "aat.kind": "psf_surrogate",
        "aat.model": type(model).__name__,
        "aat.lens_name": lens.name,
        "aat.lens_hash": lens.prescription_hash(),
        "aat.sensor_mm": json.dumps([sen.width_mm, sen.height_mm]),
        "aat.sensor_px": json.dumps([sen.width_px, sen.height_px]),
        "aat.pixel_um": f"{sen.pixel_mm * 1000:.6g}",
        "aat.kernel_size": str(model.k),
        "aat.margin_px": str(model.margin_px),
        "aat.depth_range_m": json.dumps([model.near_m, model.far_m]),
        "aat.focus_range_m": json.dumps([model.near_m, model.far_m]),
        "aat.distances": "metres from the sensor plane along the optical axis",
        "aat.inputs": INPUTS_DOC,
        "aat.outputs": OUTPUTS_DOC,
        "aat.efl_mm": f"{model.efl_mm:.9g}",
        "aat.entrance_pupil_mm": f"{model.epd_mm:.9g}",
        **optics_metadata(lens, model.near_m),
    }
    md.update({f"aat.{k}": (v if isinstance(v, str) else json.dumps(v)) for k, v in (extra or {}).items()})
    return md


def optics_metadata(lens: Lens, near_m: float = DEFAULT_NEAR_M) -> dict[str, str]:
    """The lens's focusing, for renderers without the ray tracer (`aat_deploy.diagnose.twin`): the real-ray focus table of
    `training.psf.geometry.focus_table_reaching(lens, near_m)` (diopters ascending, sensor z in mm from the first
    vertex; near_m: the surrogate's nearest distance) and the paraxial exit pupil (mm from the first vertex), as
    JSON."""
    t = focus_table_reaching(lens, near_m)
    return {TABLE_KEYS[0]: json.dumps(t.diopters.tolist()), TABLE_KEYS[1]: json.dumps(t.sensor_z_mm.tolist()),
            EXIT_PUPIL_KEY: json.dumps(float(paraxial_data(lens).exit_pupil_z_mm))}


def stamp_optics_metadata(path, lens: Lens, best_focus=None) -> dict[str, str]:
    """Add (or refresh) the `optics_metadata` keys of an exported surrogate without retraining; the lens must be
    the one it was fitted for (prescription hash). `best_focus`: also the lens's best-focus map
    (`aat_deploy.focus.bestfocus.BestFocusMap`, under its METADATA_KEY), which the runtime's aberration-aware
    classical depth from focus reads. The file is replaced atomically. Returns the keys written."""
    import onnx

    path = Path(path)
    m = onnx.load(str(path))
    props = {p.key: p for p in m.metadata_props}
    if "aat.lens_hash" not in props or props["aat.lens_hash"].value != lens.prescription_hash():
        raise ValueError(f"{path}: not a PSF surrogate of {lens.name!r} (lens hash differs)")
    near = json.loads(props["aat.focus_range_m"].value)[0] if "aat.focus_range_m" in props else DEFAULT_NEAR_M
    md = optics_metadata(lens, near)
    if best_focus is not None:
        from aat_deploy.focus.bestfocus import METADATA_KEY

        if best_focus.lens_hash and best_focus.lens_hash != lens.prescription_hash():
            raise ValueError(f"{path}: the best-focus map is of another lens than {lens.name!r}")
        md[METADATA_KEY] = json.dumps(best_focus.to_dict())
    for k, v in md.items():
        if k in props:
            props[k].value = v
        else:
            m.metadata_props.add(key=k, value=v)
    with atomic_file(path) as tmp:
        onnx.save(m, str(tmp))
    return md


def export_psf_onnx(model: PSFModel, lens: Lens, path, extra_metadata: dict | None = None, force: bool = False,
                    check: bool = True) -> dict[str, str]:
    """Write `model` to ONNX (dynamic batch) with metadata; check onnxruntime against torch (`parity`, relative,
    at most `PARITY_TOL`)."""
    import onnx

    path = Path(path)
    if path.exists() and not force:
        raise FileExistsError(f"{path}: exists (use --force to overwrite)")
    model = model.eval().float()
    wrapper = _Wrapper(model)
    q = torch.tensor([[0.1, 0.2, 1.0, 1.5], [0.9, -0.8, 0.4, 5.0]], dtype=torch.float32)
    with atomic_file(path) as tmp:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the legacy exporter's deprecation notice
            torch.onnx.export(wrapper, (q,), str(tmp), input_names=["query"], output_names=["kernels", "scale"],
                              dynamic_axes={"query": {0: "batch"}, "kernels": {0: "batch"}, "scale": {0: "batch"}},
                              opset_version=17, dynamo=False)
        m = onnx.load(str(tmp))
        md = metadata(model, lens, extra_metadata)
        for k, v in md.items():
            m.metadata_props.add(key=k, value=v)
        onnx.save(m, str(tmp))
        if check:
            err = parity(wrapper, tmp)
            if err > PARITY_TOL:
                raise RuntimeError(f"{path}: onnxruntime differs from torch by {err:.2e} relative "
                                   f"(> {PARITY_TOL:.0e})")
    return md


# onnxruntime vs torch, relative (see `parity`). Kernels are a softmax over an MLP's logits: float32 rounding (unit
# roundoff 6e-8) through its layers is ~1e-6 of the logits, times their spread in a sharp near-focus kernel (tens);
# measured 2e-6 (paper-50 RotPSF) to 6e-5 (RF50 at 31 um pixels) of the energy, the cell size 7e-6. 1e-3 leaves a
# factor >10 for other CPUs' kernels and is still below what the layered renderer resolves (0.35 % of the exact).
PARITY_TOL = 1e-3


def parity(wrapper: nn.Module, onnx_path, n: int = 2048, seed: int = 0) -> float:
    """Largest relative difference between torch and onnxruntime on random queries over the valid range: kernel
    cells over the largest kernel energy (sum) of the batch, cell sizes over themselves (>= 1)."""
    import onnxruntime as ort

    m = wrapper.model
    rng = np.random.default_rng(seed)
    inv = rng.uniform(m.d_lo, m.d_hi, (n, 2))
    q = np.concatenate([rng.uniform(-1, 1, (n, 2)), 1 / inv], 1).astype(np.float32)
    q[:8, :2] = [[0, 0], [0, 1], [1, 0], [0, -1], [-1, 0], [1, 1], [-1, -1], [0, 0]]  # axis and edges exactly
    sess = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    k_ort, s_ort = sess.run(None, {"query": q})
    with torch.no_grad():
        k_t, s_t = (t.numpy() for t in wrapper(torch.from_numpy(q)))
    energy = max(float(k_t.sum((1, 2)).max()), 1e-30)
    return max(float(np.abs(k_ort - k_t).max()) / energy, float((np.abs(s_ort - s_t) / s_t).max()))
