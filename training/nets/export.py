"""Export a trained DfF model to ONNX with the metadata of docs/contracts.md ("DfF model").

Graph: inputs `stack` (B, S, 3, H, W) float32 normalised by aat_deploy.infer.normalise.normalise_stack, frames sorted
near to far, H and W multiples of `aat.size_multiple`; `focus_m` (B, S) float32 metres from the sensor plane.
Field-aware models (`aat.field_channels` = 2) take a third input `field_xy` (B, 2, H, W) float32: each pixel's
normalised sensor position (x right, y up, +-1 at the sensor edges; padded pixels continue the ramp).
Outputs `depth_m` (B, H, W), `aif` (B, 3, H, W), `std_m` (B, H, W). B, S, H, W are dynamic; both nets have no
shape-derived kernels, so one export is exact at every shape (checked against torch at three shapes when
written). The graph neither sorts nor pads: the runtime does (as `training.nets.model.predict` does in torch).
"""

from __future__ import annotations

import hashlib
import json
import warnings
from importlib import metadata as importlib_metadata
from pathlib import Path

import numpy as np
import torch

from aat_deploy.infer.normalise import DESCRIPTION as NORMALISATION
from aat_deploy.io.atomic import atomic_file
from aat_deploy.lens.schema import Lens
from training.nets.model import DfFNet

DISTANCES = "metres from the sensor plane along the optical axis"
# onnxruntime vs torch, relative to the inputs' magnitude (see `parity`). Float32 (unit roundoff 6e-8) through some
# 25 convolutions of up to ~1,700-term sums, summed in another order by each kernel and CPU: ~1e-6 per layer, up to
# ~1e-4 at the outputs with the softmax head's sharp logits (measured 5e-7 to 1.4e-5 on exports, 1.3e-4 for a random
# DFVNet at 960x640, BENCHMARKS.md). 1e-3 (1 cm at 10 m; the nets err by dm) keeps a margin; a wrong weight: > 1e-1.
PARITY_TOL = 1e-3
FIELD_CONVENTION = ("input field_xy (B, 2, H, W): normalised sensor position of each pixel centre, x right, y up, "
                    "-1..1 from edge to edge of the sensor (aat_deploy.optics.field.pixel_fields); padding continues it")


def config_hash(config: dict) -> str:
    """SHA-256 (first 16 hex) of a JSON-serialisable config, key order ignored."""
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()[:16]


def package_version() -> str:
    try:
        return importlib_metadata.version("aat")
    except importlib_metadata.PackageNotFoundError:
        return "unknown"


def dff_metadata(model: DfFNet, lens: Lens, *, simulator: str, effects: list[str],
                 focus_range_m: tuple[float, float], stack_range: tuple[int, int], config_hash: str,
                 extra: dict | None = None) -> dict[str, str]:
    """metadata_props for a DfF model: every key of docs/contracts.md, strings (lists/numbers JSON-encoded)."""
    from aat_deploy.optics.paraxial import paraxial_data

    if simulator not in ("aat", "thin_lens"):
        raise ValueError(f"simulator must be 'aat' or 'thin_lens', got {simulator!r}")
    if not model.name or not model.size:
        raise ValueError("dff_metadata: the model has no net name / size (build it with build_model)")
    par = paraxial_data(lens)
    sen = lens.sensor
    md = {
        "aat.kind": "dff",
        "aat.net": model.name,
        "aat.size": model.size,
        "aat.simulator": simulator,
        "aat.effects": json.dumps(list(effects)),
        "aat.lens_name": lens.name,
        "aat.lens_hash": lens.prescription_hash(),
        "aat.focal_length_mm": f"{par.efl_mm:.9g}",
        "aat.f_number": f"{par.fno:.6g}",
        "aat.sensor_mm": json.dumps([sen.width_mm, sen.height_mm]),
        "aat.sensor_px": json.dumps([sen.width_px, sen.height_px]),
        "aat.pixel_um": f"{sen.pixel_mm * 1000:.6g}",
        "aat.focus_range_m": json.dumps([float(focus_range_m[0]), float(focus_range_m[1])]),
        "aat.stack_min": str(int(stack_range[0])),
        "aat.stack_max": str(int(stack_range[1])),
        "aat.size_multiple": str(model.size_multiple),
        "aat.input_normalisation": NORMALISATION,
        "aat.config_hash": config_hash,
        "aat.version": package_version(),
        "aat.distances": DISTANCES,
        "aat.n_params": str(model.n_params),
    }
    if model.field_channels:
        md["aat.field_channels"] = str(model.field_channels)
        md["aat.field_convention"] = FIELD_CONVENTION
    md.update({f"aat.{k}": (v if isinstance(v, str) else json.dumps(v)) for k, v in (extra or {}).items()})
    return md


def _example(b: int, s: int, h: int, w: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    stack = torch.rand(b, s, 3, h, w, generator=g)
    focus = torch.sort(torch.rand(b, s, generator=g) * 5 + 0.3, dim=1).values
    field = torch.rand(b, 2, h, w, generator=g) * 2 - 1
    return stack, focus, field


def _feeds(model: DfFNet, stack, focus, field) -> tuple[tuple, dict]:
    """Torch arguments and onnxruntime feeds of one example (field only for field-aware models)."""
    if model.field_channels:
        return (stack, focus, field), {"stack": stack.numpy(), "focus_m": focus.numpy(), "field_xy": field.numpy()}
    return (stack, focus), {"stack": stack.numpy(), "focus_m": focus.numpy()}


def parity(model: DfFNet, onnx_path, shapes: list[tuple[int, int, int, int]]) -> float:
    """Largest relative difference between torch and onnxruntime over all outputs at each (B, S, H, W): max |ORT -
    torch| of depth_m and std_m over the largest focus distance, of aif over the largest stack value (the
    magnitudes those outputs are made from; rounding is relative to them, also where an output is near 0)."""
    import onnxruntime as ort

    sess = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    worst = 0.0
    model = model.eval()
    for i, shp in enumerate(shapes):
        args, feeds = _feeds(model, *_example(*shp, seed=i))
        outs = sess.run(None, feeds)
        with torch.no_grad():
            ref = model(*args)
        stack, focus = args[0], args[1]
        scales = (float(focus.abs().max()), float(stack.abs().max()), float(focus.abs().max()))  # depth, aif, std
        for o, r, s in zip(outs, ref, scales):
            if o.shape != tuple(r.shape):
                raise RuntimeError(f"onnxruntime output shape {o.shape} != torch {tuple(r.shape)} at {shp}")
            worst = max(worst, float(np.abs(o - r.numpy()).max()) / max(s, 1e-30))
    return worst


def export_dff_onnx(model: DfFNet, path, metadata: dict[str, str], *, force: bool = False,
                    check_shapes: list[tuple[int, int, int, int]] | None = None, opset: int = 17) -> float:
    """Write `model` to ONNX at `path` (atomic: temporary file then rename; refuses to overwrite unless force)
    with `metadata` (see dff_metadata). Checks onnxruntime against torch at `check_shapes` (B, S, H, W)
    (default: three different shapes) and refuses to write if they differ by more than `PARITY_TOL` (relative,
    see `parity`). Returns that relative difference."""
    path = Path(path)
    if path.exists() and not force:
        raise FileExistsError(f"{path}: exists (use --force to overwrite)")
    m = model.size_multiple
    shapes = check_shapes or [(1, 5, 2 * m, 2 * m), (2, 3, m, 3 * m), (1, 8, 3 * m, 2 * m)]
    model = model.eval().float()
    args, _ = _feeds(model, *_example(1, 4, 2 * m, 2 * m))
    names = ["stack", "focus_m"] + (["field_xy"] if model.field_channels else [])
    axes = {"stack": {0: "B", 1: "S", 3: "H", 4: "W"}, "focus_m": {0: "B", 1: "S"},
            "depth_m": {0: "B", 1: "H", 2: "W"}, "aif": {0: "B", 2: "H", 3: "W"}, "std_m": {0: "B", 1: "H", 2: "W"}}
    if model.field_channels:
        axes["field_xy"] = {0: "B", 2: "H", 3: "W"}
    return _write_checked(model, path, args, names, axes, metadata, lambda tmp: parity(model, tmp, shapes), opset)


def _write_checked(model, path: Path, args: tuple, names: list[str], axes: dict, metadata: dict[str, str],
                   check, opset: int) -> float:
    """torch.onnx.export (legacy exporter, dynamic axes) into a temporary file, metadata added, `check(tmp)` (the
    relative ORT-vs-torch difference) refused above PARITY_TOL, then renamed into place. Returns the difference."""
    import onnx

    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(path) as tmp:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the legacy exporter's deprecation notice
            torch.onnx.export(model, args, str(tmp), input_names=names,
                              output_names=["depth_m", "aif", "std_m"], opset_version=opset, dynamo=False,
                              dynamic_axes=axes)
        proto = onnx.load(str(tmp))
        for k, v in metadata.items():
            proto.metadata_props.add(key=k, value=str(v))
        onnx.save(proto, str(tmp))
        err = check(tmp)
        if err > PARITY_TOL:
            raise RuntimeError(f"{path}: onnxruntime differs from torch by {err:.2e} of the inputs' magnitude "
                               f"(> {PARITY_TOL:g})")
    return err


def read_metadata(path) -> dict[str, str]:
    """metadata_props of an ONNX file as a dict."""
    import onnx

    return {p.key: p.value for p in onnx.load(str(path), load_external_data=False).metadata_props}


# -- the any-camera model (training.nets.dfvaat): per-pixel focus inputs -------------------------------------------
FOCUS_MAP_INPUTS = ("input focus_diopters (B, S, H, W): object diopters (1/m, distances from the sensor plane) in best "
                    "focus in each frame at each pixel; input defocus_px_per_d (B, 1, H, W): blur-diameter growth "
                    "(px) per diopter of defocus at each pixel; frames sorted near to far (descending diopters)")


def focus_map_metadata(model, *, effects: list[str], stack_range: tuple[int, int], config_hash: str,
                       k_range: tuple[float, float], extra: dict | None = None) -> dict[str, str]:
    """metadata_props of the any-camera model (docs/contracts.md, "DfF model with focus maps"): no lens, sensor or
    focus range of its own; it declares the inputs it needs and the defocus scales it was trained on."""
    md = {
        "aat.kind": "dff",
        "aat.net": model.name,
        "aat.size": model.size,
        "aat.inputs": "focus_map",
        "aat.focus_map_inputs": FOCUS_MAP_INPUTS,
        "aat.simulator": "any_camera",
        "aat.effects": json.dumps(list(effects)),
        "aat.stack_min": str(int(stack_range[0])),
        "aat.stack_max": str(int(stack_range[1])),
        "aat.defocus_px_per_d_range": json.dumps([float(k_range[0]), float(k_range[1])]),
        "aat.size_multiple": str(model.size_multiple),
        "aat.input_normalisation": NORMALISATION,
        "aat.config_hash": config_hash,
        "aat.version": package_version(),
        "aat.distances": DISTANCES,
        "aat.n_params": str(model.n_params),
    }
    md.update({f"aat.{k}": (v if isinstance(v, str) else json.dumps(v)) for k, v in (extra or {}).items()})
    return md


def _focus_map_example(b: int, s: int, h: int, w: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    stack = torch.rand(b, s, 3, h, w, generator=g)
    near, far = 1.0 / (0.3 + torch.rand(b, generator=g)), 0.1 * torch.rand(b, generator=g)
    t = torch.linspace(0, 1, s)[None, :, None, None]
    field = 0.05 * torch.rand(b, 1, h, w, generator=g)
    fd = near[:, None, None, None] * (1 - t) + far[:, None, None, None] * t + field
    k = 1.0 + 40 * torch.rand(b, 1, 1, 1, generator=g) * (1 + 0.1 * torch.rand(b, 1, h, w, generator=g))
    return stack, fd, k


def parity_focus_map(model, onnx_path, shapes: list[tuple[int, int, int, int]]) -> float:
    """`parity` for the any-camera model: largest relative ORT-vs-torch difference over its outputs at each
    (B, S, H, W) (depth and std over the largest in-focus distance, aif over the stack's largest value)."""
    import onnxruntime as ort

    sess = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    worst = 0.0
    model = model.eval()
    for i, shp in enumerate(shapes):
        stack, fd, k = _focus_map_example(*shp, seed=i)
        outs = sess.run(None, {"stack": stack.numpy(), "focus_diopters": fd.numpy(), "defocus_px_per_d": k.numpy()})
        with torch.no_grad():
            ref = model(stack, fd, k)
        dmax = float((1.0 / fd.clamp_min(1e-3)).max())
        for o, r, s in zip(outs, ref, (dmax, float(stack.abs().max()), dmax)):
            if o.shape != tuple(r.shape):
                raise RuntimeError(f"onnxruntime output shape {o.shape} != torch {tuple(r.shape)} at {shp}")
            worst = max(worst, float(np.abs(o - r.numpy()).max()) / max(s, 1e-30))
    return worst


def export_focus_map_onnx(model, path, metadata: dict[str, str], *, force: bool = False,
                          check_shapes: list[tuple[int, int, int, int]] | None = None, opset: int = 17) -> float:
    """Write the any-camera model to ONNX (atomic, no overwrite unless force), dynamic B, S, H, W, exported at one
    shape and checked against torch at others (default: four, none the export's); refuses beyond PARITY_TOL."""
    path = Path(path)
    if path.exists() and not force:
        raise FileExistsError(f"{path}: exists (use --force to overwrite)")
    m = model.size_multiple
    shapes = check_shapes or [(1, 3, m, 3 * m), (1, 5, 2 * m, 2 * m), (2, 9, 3 * m, 2 * m), (1, 16, 2 * m, 3 * m)]
    model = model.eval().float()
    args = _focus_map_example(1, 4, 2 * m, 2 * m)
    axes = {"stack": {0: "B", 1: "S", 3: "H", 4: "W"}, "focus_diopters": {0: "B", 1: "S", 2: "H", 3: "W"},
            "defocus_px_per_d": {0: "B", 2: "H", 3: "W"},
            "depth_m": {0: "B", 1: "H", 2: "W"}, "aif": {0: "B", 2: "H", 3: "W"}, "std_m": {0: "B", 1: "H", 2: "W"}}
    return _write_checked(model, path, args, ["stack", "focus_diopters", "defocus_px_per_d"], axes, metadata,
                          lambda tmp: parity_focus_map(model, tmp, shapes), opset)
