"""Start a DfF net from trained weights for fine-tuning: an exported DfF ONNX model or a training checkpoint.

ONNX models written by `training.nets.export` (torch.onnx, eval mode) do not keep every parameter under its
state_dict name: each BatchNorm that follows a bias-free convolution is folded into that convolution, whose
weight and bias become anonymous tensors (``onnx::Conv_638``). The mapping back:

- an initializer whose name is a state_dict key is copied as is;
- a Conv / ConvTranspose node's name carries its module scope
  (``/net/encoder/stages.0/stages.0.0/body/body.0/body.0.0/Conv`` is module ``net.encoder.stages.0.0.body.0.0``;
  scopes skip indexed containers such as nn.ModuleDict, matched as the unique convolution path containing them):
  its weight goes to that module, its bias to the module's own bias or, when the module has none, to the
  BatchNorm that follows it in its ``nn.Sequential`` (the folded one);
- modules an eval-mode forward never calls (DFVNet's coarse-level head, used only for deep supervision) are not
  in the graph and keep their fresh initialisation;
- a folded BatchNorm becomes ``y + b`` exactly in eval mode: running mean m, running variance v, weight
  sqrt(v + eps), bias b + m. (m, v) are the statistics of the convolution's output over a few training items
  (`recalibrate`), so that batch statistics in training mode normalise about as the original layer did;
  without data m = 0, v = 1 - eps.

Every parameter and buffer of the net must be covered, and the loaded torch net must reproduce onnxruntime's
outputs (to `training.nets.export.PARITY_TOL` of the inputs' magnitude, `training.nets.export.parity`: float32
rounding, which differs between CPUs); otherwise `InitError` says what is wrong.
"""

from __future__ import annotations

import copy
from pathlib import Path

import torch
from torch import nn

from aat_deploy.errors import AatError
from training.nets import registry
from training.nets.export import PARITY_TOL
from training.nets.model import DfFNet, pad_to_multiple, sort_by_focus


class InitError(AatError):
    """An --init file that cannot initialise the requested net."""


def module_path(node_name: str) -> str:
    """Module path of an exported node from its scope name: '/net/decoders.0/classify/classify.1/Conv' ->
    'net.decoders.0.classify.1' (a scope 'parent.k' under scope 'parent' is child k)."""
    parts = [p for p in node_name.split("/") if p][:-1]
    out: list[str] = []
    prev = None
    for p in parts:
        out.append(p[len(prev) + 1:] if prev is not None and p.startswith(prev + ".") else p)
        prev = p
    return ".".join(out)


def onnx_net_kind(path) -> tuple[str, str]:
    """(net, size) from a DfF ONNX model's metadata (aat.net, aat.size)."""
    from training.nets.export import read_metadata

    md = read_metadata(path)
    if md.get("aat.kind") != "dff":
        raise InitError(f"{path}: not an aat DfF model (aat.kind = {md.get('aat.kind')!r})")
    return md.get("aat.net", ""), md.get("aat.size", "")


def checkpoint_net_kind(path) -> tuple[str, str]:
    """(net, size) of a training checkpoint (model.pt / last.pt)."""
    from training.train.checkpoint import load

    cfg = load(path).get("config") or {}
    return str(cfg.get("net", "")), str(cfg.get("size", ""))


def init_kind(path) -> tuple[str, str]:
    """(net, size) of an --init file (.onnx or a checkpoint)."""
    return onnx_net_kind(path) if Path(path).suffix.lower() == ".onnx" else checkpoint_net_kind(path)


def _is_subsequence(short: list[str], long: list[str]) -> bool:
    it = iter(long)
    return all(any(x == y for y in it) for x in short)


def _find_conv(convs: dict[str, nn.Module], scope_path: str, path, node_name: str) -> str:
    """The convolution a node belongs to: its scope path, or the one convolution whose path contains the scope's
    components in order and ends like it (scopes skip containers that are indexed, not called: nn.ModuleDict)."""
    if scope_path in convs:
        return scope_path
    want = scope_path.split(".")
    hits = [n for n in convs if n.split(".")[-1] == want[-1] and _is_subsequence(want, n.split("."))]
    if len(hits) != 1:
        raise InitError(f"{path}: node {node_name} matches {len(hits)} convolutions of the net "
                        f"({hits[:3]}); was it exported from another net?")
    return hits[0]


def _next_batchnorm(model: nn.Module, conv_path: str) -> tuple[str, nn.Module]:
    parent, _, idx = conv_path.rpartition(".")
    if not idx.isdigit():
        raise InitError(f"convolution {conv_path} has a folded bias but is not inside an nn.Sequential")
    bn_path = f"{parent}.{int(idx) + 1}"
    try:
        bn = model.get_submodule(bn_path)
    except AttributeError:
        raise InitError(f"no BatchNorm after convolution {conv_path}") from None
    if not isinstance(bn, nn.modules.batchnorm._BatchNorm):
        raise InitError(f"{bn_path} after convolution {conv_path} is {type(bn).__name__}, not a BatchNorm")
    return bn_path, bn


def _unused_in_inference(model: DfFNet) -> set[str]:
    """Paths of modules whose parameters do not reach the eval-mode outputs (e.g. DFVNet's coarse
    deep-supervision head): the exported graph does not contain them, so they keep their fresh initialisation."""
    m = model.size_multiple
    probe = copy.deepcopy(model).eval()
    depth, aif, std = probe(torch.rand(1, 2, 3, 2 * m, 2 * m), torch.tensor([[0.5, 2.0]]))
    (depth.sum() + aif.sum() + std.sum()).backward()
    return {n for n, mod in probe.named_modules()
            if any(True for _ in mod.parameters(recurse=False))
            and all(p.grad is None for p in mod.parameters(recurse=False))}


def load_onnx_weights(model: DfFNet, path) -> list[tuple[nn.Module, torch.Tensor]]:
    """Copy an exported model's weights into `model` (see module docstring). Returns the folded BatchNorms as
    (module, folded bias) pairs, already set to the exact eval-mode identity-plus-bias."""
    import onnx
    from onnx import numpy_helper

    proto = onnx.load(str(path))
    inits = {i.name: torch.from_numpy(numpy_helper.to_array(i).copy()) for i in proto.graph.initializer}
    state = model.state_dict()
    done: set[str] = set()
    folded: list[tuple[nn.Module, torch.Tensor]] = []

    def put(key: str, value: torch.Tensor) -> None:
        if key not in state:
            raise InitError(f"{path}: tensor for {key}, which the {model.name} {model.size} net does not have")
        if tuple(state[key].shape) != tuple(value.shape):
            raise InitError(f"{path}: {key} has shape {tuple(value.shape)}, the net expects {tuple(state[key].shape)}"
                            " (another net or size?)")
        state[key].copy_(value.to(state[key].dtype))
        done.add(key)

    convs = {n: m for n, m in model.named_modules() if isinstance(m, nn.modules.conv._ConvNd)}
    for name, value in inits.items():
        if name in state:
            put(name, value)
    for node in proto.graph.node:
        anon = [i for i in node.input[1:] if i in inits and i not in state]
        if node.op_type not in ("Conv", "ConvTranspose") or not anon:
            continue
        mpath = _find_conv(convs, module_path(node.name), path, node.name)
        conv = convs[mpath]
        w_name = node.input[1]
        b_name = node.input[2] if len(node.input) > 2 and node.input[2] else None
        if w_name in anon:
            put(f"{mpath}.weight", inits[w_name])
        if b_name in anon:
            if conv.bias is not None:
                put(f"{mpath}.bias", inits[b_name])
            else:
                bn_path, bn = _next_batchnorm(model, mpath)
                b = inits[b_name].to(bn.bias.dtype)
                with torch.no_grad():
                    bn.weight.fill_(1.0)
                    bn.bias.copy_(b)
                    bn.running_mean.zero_()
                    bn.running_var.fill_(1.0 - bn.eps)
                done.update(f"{bn_path}.{k}" for k in ("weight", "bias", "running_mean", "running_var"))
                folded.append((bn, b.clone()))
    unused = _unused_in_inference(model)
    missing = [k for k in state if k not in done and not k.endswith("num_batches_tracked")
               and k.rpartition(".")[0] not in unused]
    if missing:
        raise InitError(f"{path}: no weights for {len(missing)} tensors of the {model.name} {model.size} net "
                        f"(first: {missing[:3]}); was it exported from another net?")
    return folded


@torch.no_grad()
def recalibrate(model: DfFNet, folded: list[tuple[nn.Module, torch.Tensor]], items) -> int:
    """Give folded BatchNorms the statistics of their input over `items` (dicts with "stack" (S, 3, H, W) and
    "focus_m" (S,)), keeping the eval-mode function exact. Returns the number of items used."""
    if not folded:
        return 0
    stats = {id(bn): [0.0, 0.0, 0.0] for bn, _ in folded}  # sum, sum of squares, count per channel

    def hook(bn, inputs, _out):
        x = inputs[0].double()
        dims = [d for d in range(x.dim()) if d != 1]
        s = stats[id(bn)]
        s[0] = s[0] + x.sum(dims)
        s[1] = s[1] + (x * x).sum(dims)
        s[2] += x.numel() / x.shape[1]

    handles = [bn.register_forward_hook(hook) for bn, _ in folded]
    was_training = model.training
    model.eval()
    n = 0
    try:
        for it in items:
            stack, focus = sort_by_focus(torch.as_tensor(it["stack"])[None].float(),
                                         torch.as_tensor(it["focus_m"])[None].float())
            model(pad_to_multiple(stack, model.size_multiple)[0], focus)
            n += 1
    finally:
        for h in handles:
            h.remove()
        model.train(was_training)
    if n == 0:
        return 0
    for bn, b in folded:
        s0, s1, cnt = stats[id(bn)]
        mean = s0 / cnt
        var = (s1 / cnt - mean * mean).clamp_min(0.0)
        bn.running_mean.copy_(mean.to(bn.running_mean.dtype))
        bn.running_var.copy_(var.to(bn.running_var.dtype))
        bn.weight.copy_(torch.sqrt(var + bn.eps).to(bn.weight.dtype))
        bn.bias.copy_((b.double() + mean).to(bn.bias.dtype))
    return n


def same_tensors(model: nn.Module, net: str, size: str) -> bool:
    """Whether a `net` of `size` has exactly `model`'s tensors (names and shapes): sizes that differ only in how
    the net computes, e.g. its padding (training.nets.dfvaat "small_replicate"), share their weights."""
    from training.nets.model import build_model
    from training.nets.registry import UnknownNet

    try:
        other = build_model(net, size, getattr(model, "field_channels", 0)).state_dict()
    except (UnknownNet, KeyError, ValueError):
        return False
    mine = model.state_dict()
    return other.keys() == mine.keys() and all(other[k].shape == mine[k].shape for k in mine)


def adds_only_a_head(model: nn.Module, net: str, size: str) -> bool:
    """Whether `model` is a `net` of `size` plus tensors of a new head only: every tensor of the other is the
    model's, same shape, and every extra one is under `model.HEAD_PREFIX` (training.nets.dfvaat's "_x" sizes)."""
    prefix = getattr(model, "HEAD_PREFIX", None)
    if prefix is None:
        return False
    from training.nets.model import build_model
    from training.nets.registry import UnknownNet

    try:
        other = build_model(net, size, getattr(model, "field_channels", 0)).state_dict()
    except (UnknownNet, KeyError, ValueError):
        return False
    mine = model.state_dict()
    extra = mine.keys() - other.keys()
    return (other.keys() <= mine.keys() and all(other[k].shape == mine[k].shape for k in other)
            and bool(extra) and all(k.startswith(prefix) for k in extra))


def init_model(model: DfFNet, path, dataset=None, n_items: int = 8) -> dict:
    """Load `path` (.onnx from training.nets.export, or a model.pt / last.pt checkpoint) into `model`, which must
    be the same net and size, or a size with the same tensors (`same_tensors`), or a checkpoint of a size it only adds a
    head to (`adds_only_a_head`: the new tensors keep their initialisation). ONNX: folded BatchNorms are recalibrated on the first `n_items` of `dataset`
    (if given) and the result is checked against onnxruntime. Returns a short description (for logs)."""
    path = Path(path)
    if not path.is_file():
        raise InitError(f"{path}: no such --init file")
    net, size = init_kind(path)
    grows = net == model.name and path.suffix.lower() != ".onnx" and adds_only_a_head(model, net, size)
    if net != model.name or (size != model.size and not same_tensors(model, net, size) and not grows):
        raise InitError(f"{path}: is a {net or '?'} {size or '?'} model; the run trains a {model.name} {model.size}")
    if size != model.size and path.suffix.lower() == ".onnx":  # its padding is in the graph, not in the weights
        raise InitError(f"{path}: an ONNX file starts only a {size} net (its padding is part of the graph); start the "
                        f"{model.size} net from the run's checkpoint (model.pt / last.pt)")
    if path.suffix.lower() == ".onnx" and registry.get(model.name).focus_maps:
        # its graph computes the focus conditioning from slices of the weights (training.nets.dfvaat.cond_bias):
        # they do not map back onto the net's tensors by name
        raise InitError(f"{path}: the any-camera net ({model.name}) starts only from a training checkpoint "
                        "(model.pt / last.pt, e.g. checkpoints/dfv_aat_v1/), not from its ONNX export")
    if path.suffix.lower() != ".onnx":
        from training.train.checkpoint import load

        if grows:  # the new head keeps its own initialisation (which starts it as the old head)
            missing = model.load_state_dict(load(path)["model"], strict=False).missing_keys
            return {"init": str(path), "kind": "checkpoint", "new_tensors": len(missing)}
        model.load_state_dict(load(path)["model"])
        return {"init": str(path), "kind": "checkpoint"}
    from training.nets.export import parity

    folded = load_onnx_weights(model, path)
    m = model.size_multiple
    err = parity(model, path, [(1, 4, 2 * m, 2 * m)])
    if err > PARITY_TOL:
        raise InitError(f"{path}: the loaded torch net differs from onnxruntime by {err:.2e} of the inputs' "
                        f"magnitude (> {PARITY_TOL:g})")
    used = 0
    if dataset is not None:
        used = recalibrate(model, folded, (dataset[i] for i in range(min(n_items, len(dataset)))))
        err = max(err, parity(model, path, [(1, 4, 2 * m, 2 * m)]))
        if err > PARITY_TOL:
            raise InitError(f"{path}: after recalibration the net differs from onnxruntime by {err:.2e} of the "
                            f"inputs' magnitude (> {PARITY_TOL:g})")
    model.train()
    return {"init": str(path), "kind": "onnx", "folded_batchnorms": len(folded), "recalibration_items": used,
            "rel_diff_vs_onnxruntime": float(err)}


__all__ = ["InitError", "init_kind", "init_model", "load_onnx_weights", "module_path", "recalibrate", "same_tensors"]
