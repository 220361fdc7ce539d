"""One any-camera ONNX file from two, chosen by the stack's frame count.

    python -m training.train.route SMALL.onnx LARGE.onnx --max-small-frames T --out models/dfv_aat.onnx [--force]

The twelfth run's net is the better one with 3-5 frames and the tenth run's with 8 or more (docs/training.md, "one
file for few and many frames"). Users type one model name and feed any S, so the file holds both nets and an ONNX
`If` on S: stacks of at most T frames run SMALL's graph, the others LARGE's. Each call runs one net, so a call costs
what that net costs; the file stores both nets' weights.

Both inputs must be any-camera models (aat.inputs focus_map) with the same inputs, outputs and input contract
(normalisation, stack range, size multiple, tiling, distances); otherwise the routed file would feed one net what
it was not trained on. The routed file keeps that contract's metadata and says what it routes in `aat.route`.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

# metadata that must agree: what the runtime feeds the net and how it reads its outputs
SHARED_KEYS = ("aat.kind", "aat.net", "aat.inputs", "aat.focus_map_inputs", "aat.simulator", "aat.effects",
               "aat.stack_min", "aat.stack_max", "aat.defocus_px_per_d_range", "aat.size_multiple", "aat.size",
               "aat.input_normalisation", "aat.distances", "aat.tile_px")
# metadata of one trained net, kept per branch in aat.route
PER_NET_KEYS = ("aat.config_name", "aat.config_hash", "aat.checkpoint_step", "aat.train_steps", "aat.n_params",
                "aat.version")


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _io(graph) -> tuple[list, list]:
    """[(name, elem_type, dims)] of a graph's inputs and outputs; dims as dim_param or dim_value."""
    def sig(v):
        t = v.type.tensor_type
        return (v.name, t.elem_type, [d.dim_param or d.dim_value for d in t.shape.dim])
    return [sig(v) for v in graph.input], [sig(v) for v in graph.output]


def _load(path: Path):
    """The ONNX model at path; ValueError (one line, naming the file) when it is not one."""
    import onnx
    from google.protobuf.message import DecodeError

    try:
        return onnx.load(str(path))
    except (DecodeError, ValueError, OSError) as e:
        why = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise ValueError(f"{path}: not an ONNX model ({why})") from None


def _branch(model, prefix: str):
    """model's graph as an If branch: every internal name and output prefixed, no inputs of its own (it reads the
    outer graph's inputs, which keep their names). The weights stay the branch's own initializers: as outer-scope
    values onnxruntime cannot fold them into the convolutions, and the routed file ran 1.3x slower."""
    import onnx.compose

    g = onnx.compose.add_prefix_graph(model.graph, prefix, rename_inputs=False, rename_outputs=True,
                                      rename_initializers=True)
    del g.input[:]
    g.name = prefix.rstrip("_")
    return g


def route_by_stack_size(small: Path, large: Path, max_small_frames: int, out: Path, *, force: bool = False
                        ) -> dict[str, str]:
    """Write `out`: stacks of S <= max_small_frames frames run `small`, the others `large`. Returns the metadata.
    Raises ValueError (one line, naming the file) when a file is not ONNX, the two models do not share their inputs,
    outputs and input contract, or T is outside the models' stack range; FileExistsError when `out` exists and not
    force."""
    import onnx
    from onnx import TensorProto, helper

    from aat_deploy.io.atomic import atomic_file

    small, large, out = Path(small), Path(large), Path(out)
    if out.exists() and not force:
        raise FileExistsError(f"{out}: exists (use --force to overwrite)")
    ms, ml = _load(small), _load(large)
    meta_s = {p.key: p.value for p in ms.metadata_props}
    meta_l = {p.key: p.value for p in ml.metadata_props}
    for path, meta in ((small, meta_s), (large, meta_l)):
        if meta.get("aat.inputs") != "focus_map":
            raise ValueError(f"{path}: not an any-camera model (aat.inputs is {meta.get('aat.inputs')!r}, "
                             "not 'focus_map')")
        if "aat.route" in meta:
            raise ValueError(f"{path}: is itself a routed model; route the nets it holds instead")
    if _io(ms.graph) != _io(ml.graph):
        raise ValueError(f"{small}: its inputs or outputs differ from {large}'s: {_io(ms.graph)} vs {_io(ml.graph)}")
    for k in SHARED_KEYS:
        if meta_s.get(k) != meta_l.get(k):
            raise ValueError(f"{small}: metadata {k} is {meta_s.get(k)!r}, {large} has {meta_l.get(k)!r}; "
                             "the routed file would feed one net what it was not trained on")
    lo, hi = int(meta_l["aat.stack_min"]), int(meta_l["aat.stack_max"])
    if not lo <= max_small_frames < hi:
        raise ValueError(f"{small}: max_small_frames {max_small_frames} must be in [{lo}, {hi - 1}] "
                         "(the models' stack range), or one net would never run")
    opsets = {(o.domain, o.version) for o in ms.opset_import} | {(o.domain, o.version) for o in ml.opset_import}
    if len({d for d, _ in opsets}) != len(opsets):
        raise ValueError(f"{small}: opset {sorted(opsets)} differs from {large}'s; export both with the same torch")

    then_g, else_g = _branch(ms, "small_"), _branch(ml, "large_")
    inputs, outputs = list(ml.graph.input), list(ml.graph.output)
    nodes = [
        # S, the stack's frame count: dim 1 of stack (B, S, 3, H, W)
        helper.make_node("Shape", ["stack"], ["route_s"], start=1, end=2, name="route_shape"),
        helper.make_node("Constant", [], ["route_t"], name="route_const",
                         value=helper.make_tensor("route_t_value", TensorProto.INT64, [1], [max_small_frames])),
        helper.make_node("LessOrEqual", ["route_s", "route_t"], ["route_le"], name="route_le"),
        helper.make_node("Squeeze", ["route_le"], ["route_cond"], name="route_squeeze"),
        helper.make_node("If", ["route_cond"], [o.name for o in outputs], name="route_if",
                         then_branch=then_g, else_branch=else_g),
    ]
    graph = helper.make_graph(nodes, "dfv_aat_routed", inputs, outputs)
    # every domain either net uses (the check above: one version each), LARGE's first
    opset_imports = list(ml.opset_import) + [o for o in ms.opset_import
                                             if o.domain not in {x.domain for x in ml.opset_import}]
    model = helper.make_model(graph, opset_imports=opset_imports, producer_name="aat training.train.route")
    model.ir_version = max(ms.ir_version, ml.ir_version)

    def net(path: Path, meta: dict) -> dict:
        return {"file": path.name, "sha256": _sha256(path), **{k.removeprefix("aat."): meta.get(k) for k in PER_NET_KEYS}}

    route = {"max_small_frames": max_small_frames, "small": net(small, meta_s), "large": net(large, meta_l)}
    meta = {k: meta_l[k] for k in SHARED_KEYS if k in meta_l}
    meta.update({
        "aat.route": json.dumps(route),
        "aat.config_name": f"{meta_s.get('aat.config_name')}+{meta_l.get('aat.config_name')}",
        "aat.config_hash": hashlib.sha256((meta_s.get("aat.config_hash", "") + meta_l.get("aat.config_hash", ""))
                                          .encode()).hexdigest()[:16],
        # stored weights (both nets); each call runs one net
        "aat.n_params": str(int(meta_s.get("aat.n_params", 0)) + int(meta_l.get("aat.n_params", 0))),
        "aat.n_params_per_call": str(max(int(meta_s.get("aat.n_params", 0)), int(meta_l.get("aat.n_params", 0)))),
        "aat.version": meta_l.get("aat.version", "unknown"),
    })
    for k, v in meta.items():
        model.metadata_props.add(key=k, value=v)
    onnx.checker.check_model(model, full_check=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(out) as tmp:
        onnx.save(model, str(tmp))
    return meta


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("small", type=Path, help="the any-camera model for stacks of at most T frames")
    ap.add_argument("large", type=Path, help="the any-camera model for stacks of more than T frames")
    ap.add_argument("--max-small-frames", type=int, required=True, help="T (frames)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--force", action="store_true", help="overwrite --out")
    a = ap.parse_args(argv)
    for p in (a.small, a.large):
        if not p.is_file():
            print(f"error: {p}: no such model file", file=sys.stderr)
            return 2
    try:
        meta = route_by_stack_size(a.small, a.large, a.max_small_frames, a.out, force=a.force)
    except (ValueError, FileExistsError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"{a.out}: stacks of <= {a.max_small_frames} frames run {a.small.name}, more run {a.large.name} "
          f"({meta['aat.n_params']} parameters stored)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
