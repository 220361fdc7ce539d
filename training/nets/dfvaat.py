"""`dfv_aat`: one depth-from-focus net for every camera, told what each frame has in focus at each pixel.

A DFVNet (training.nets.dfvnet, the small configuration) told, besides the RGB frames, two channels made from what
the camera's user knows:
- `focus_diopters` (B, S, H, W): the object diopters (1/m, distances from the sensor plane) in best focus in frame s
  at each pixel (a thin lens's nominal focus, a traced lens's best-focus map, or a calibration);
- `defocus_px_per_d` (B, 1, H, W): how fast blur grows with defocus (px of blur diameter per diopter), from focal
  length, f-number and pixel pitch, or measured.
Channel 1 is each frame's defocus position in pixels of blur, k (D_s - mean_s D_s) / 16: how much sharper or blurrier
than its neighbours frame s makes a point, whatever the camera; channel 2 is log2(k) / 4. They enter every level's
per-frame features as a bias, a 1x1 convolution of the channels averaged down to that level's scale (`Conditioned
DFVNet`, computed in the cheaper order `cond_bias` documents, the same math), not as image channels: a nearly
constant image channel through the zero-padded 7x7 stem marks the image border, and the first run's net learnt rings
from the border instead of focus. The head interpolates the per-pixel focus diopters: D = sum_s p_s D_s(pixel) with
p = softmax over S, depth_m = 1 / D. A pixel that is sharpest in frame s is placed where that frame really focuses at
that pixel, so the map's aberrations (field curvature, tilt, astigmatism) need not be learnt: the net is
aberration-aware for lenses it never saw.

Every kernel is shape-agnostic (as DFVNet's), so one ONNX export runs at any S (>= 3), H, W (multiples of 32).
Frames are sorted near -> far (descending mean diopters); the runtime sorts and pads, as `predict` does here.
"""

from __future__ import annotations

from dataclasses import replace

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from training.nets.blocks import count_params
from training.nets.dfvnet import DFVNET_CONFIGS, DFVNet, DFVNetConfig

NET_NAME = "dfvaat"
MIN_DIOPTERS = 1e-3  # 1 km: depth of a pixel whose interpolated focus is at or past infinity
EXTRA_CHANNELS = 2
# the small DFVNet with a slightly narrower context fusion, so that the conditioning leaves the parameter count at or
# below the small DFVNet's (902,806)
# "small_replicate": the same net padding with its edge values on every padded axis, the 3-D convs' frame axis
# included (training.nets.blocks.set_padding_mode; reflection fails on 32 px images), which hardly marks the image
# border: do the nets fail on whole frames because zero padding does? (docs/training.md)
CONFIGS = {"small": replace(DFVNET_CONFIGS["small"], context_fuse=62)}
CONFIGS["small_replicate"] = replace(CONFIGS["small"], pad_mode="replicate")
# "<size>_x": the same net with `EndExtrapolation` after its head, so a pixel can be placed beyond its own frames;
# "<size>_xb": the same, bounded (`EndExtrapolation(bounded=True)`: no pixel past twice its far frame's distance);
# "<size>_xbk": bounded, and also told each end spacing in blur pixels (`EndExtrapolation(blur_spacing=True)`)
EXTRAPOLATING = "_x"
BOUNDED = "_xb"
BOUNDED_BLUR = "_xbk"
HEADS = (BOUNDED_BLUR, BOUNDED, EXTRAPOLATING)  # longest first: a size ends with at most one
SIZES = (*CONFIGS, *(k + h for h in reversed(HEADS) for k in CONFIGS))


def head_of(size: str) -> str:
    """The extrapolating head a size names ("small_replicate_xb" -> "_xb"), "" for none."""
    return next((h for h in HEADS if size.endswith(h)), "")


def base_size(size: str) -> str:
    """The DFVNet configuration a size names ("small_replicate_x", "small_replicate_xbk" -> "small_replicate")."""
    return size.removesuffix(head_of(size))


def focus_channels(focus_diopters: Tensor, defocus_px_per_d: Tensor) -> Tensor:
    """(B, S, H, W), (B, 1, H, W) -> (B, S, 2, H, W): blur position k (D_s - mean D) / 16 and log2(k) / 4, the
    conditioning channels by their definition (the net computes their pooled projection as `cond_bias` does)."""
    k = defocus_px_per_d.clamp_min(1e-3)
    pos = (focus_diopters - focus_diopters.mean(1, keepdim=True)) * k / 16.0
    lk = (torch.log2(k) / 4.0).expand_as(focus_diopters)
    return torch.stack([pos, lk], 2)


def cond_inputs(focus_diopters: Tensor, defocus_px_per_d: Tensor) -> tuple[Tensor, Tensor]:
    """(B, S, H, W), (B, 1, H, W) -> D_s k (B, S, H, W) and log2(k) / 4 (B, 1, H, W), k clamped as in
    `focus_channels`: what `ConditionedDFVNet` pools into `focus_channels`' projection."""
    k = defocus_px_per_d.clamp_min(1e-3)
    return focus_diopters * k, torch.log2(k) / 4.0


def softmax_frames(logits: Tensor) -> Tensor:
    """softmax over dim 1 (frames). In an ONNX export it is written as exp(x - max) / sum: onnxruntime's Softmax on a
    non-last axis transposes the tensor there and back, 7x slower at 8 x 640 x 960 (benchmarks/probes/
    anycam_runtime_profile.py); the same function, equal to float rounding."""
    if not torch.onnx.is_in_onnx_export():
        return torch.softmax(logits, dim=1)
    e = torch.exp(logits - logits.amax(1, keepdim=True))
    return e / e.sum(1, keepdim=True)


class EndExtrapolation(nn.Module):
    """How far beyond its end frames a pixel lies, in units of the end frames' spacing, from the shape of its focus
    curve there: logits (B, S, H, W) sorted near -> far -> (e_near, e_far), each (B, H, W) >= 0.

    A convex combination of the frames' diopters cannot leave [D_far, D_near] at a pixel, yet 19-26 % of the training
    pixels lie beyond their own frames (few frames at one end of a sweep, field curvature), with an error floor of
    3.8 frame spacings (docs/training.md, "Out-of-range pixels"). If the focus curve still rises at an end frame,
    the peak lies beyond it, farther the steeper the rise (a Gaussian-like curve in log: the slope between the last
    two frames grows linearly with the peak's distance). Inputs per end: the two last logit steps and the end
    logit's margin over the log-sum-exp (how much of the weight the end frame holds); a 1x1 MLP, softplus. Its
    last bias starts at -6 (e ~ 0.0025): the head starts as the interpolating one.

    bounded: e <= E_MAX spacings at either end (a smooth cap, e_max tanh(e / e_max)), and `focus_map_head` holds the far
    end's move to FAR_FRACTION of the far frame's diopters, so no pixel lands past twice its far frame's distance
    (the unbounded head carried 1.2-2.2 % of validation pixels to the 1 km clamp, docs/training.md).

    blur_spacing: a fourth input per end, log2 of the end spacing in blur pixels (defocus px/D times the end gap in
    D) / 4. The curve's shape over one spacing says how far its peak lies only once the spacing's width in blur is
    known: a peak *at* the end frame and one *beyond* it look alike otherwise (docs/training.md, the fifteenth run).
    forward then takes `gaps_px` = (near, far), each (B, H, W)."""

    E_MAX = 4.0  # end spacings; the out-of-range error floor measured 3.8 (docs/training.md)
    FAR_FRACTION = 0.5  # of the far frame's diopters: depth at most 2x the far frame's distance

    def __init__(self, hidden: int = 8, bounded: bool = False, blur_spacing: bool = False):
        super().__init__()
        self.bounded = bounded
        self.blur_spacing = blur_spacing
        n_in = 4 if blur_spacing else 3
        self.mlp = nn.ModuleList(nn.Sequential(nn.Conv2d(n_in, hidden, 1), nn.ReLU(), nn.Conv2d(hidden, 1, 1))
                                 for _ in range(2))
        for m in self.mlp:
            nn.init.zeros_(m[2].weight)
            nn.init.constant_(m[2].bias, -6.0)

    def forward(self, logits: Tensor, gaps_px: tuple[Tensor, Tensor] | None = None) -> tuple[Tensor, Tensor]:
        if self.blur_spacing and gaps_px is None:
            raise ValueError("EndExtrapolation(blur_spacing=True): needs gaps_px, the end spacings in blur pixels")
        lse = torch.logsumexp(logits, 1)
        out = []
        for end, (mlp, (a, b, c)) in enumerate(zip(self.mlp, ((0, 1, 2), (-1, -2, -3)))):
            feats = [logits[:, a] - logits[:, b], logits[:, b] - logits[:, c], logits[:, a] - lse]
            if self.blur_spacing:
                feats.append(torch.log2(gaps_px[end].clamp_min(1e-3)) / 4.0)
            x = torch.stack(feats, 1)
            e = F.softplus(mlp(x))[:, 0]
            out.append(self.E_MAX * torch.tanh(e / self.E_MAX) if self.bounded else e)
        return out[0], out[1]


def focus_map_head(logits: Tensor, stack: Tensor | None, focus_diopters: Tensor,
                   extrapolation: EndExtrapolation | None = None, defocus_px_per_d: Tensor | None = None,
                   ) -> tuple[Tensor, Tensor | None, Tensor, Tensor]:
    """logits (B, S, H, W), stack (B, S, 3, H, W) or None, focus_diopters (B, S, H, W) sorted near -> far,
    defocus_px_per_d (B, 1, H, W) (what an `extrapolation` with blur_spacing needs) ->
    depth_m (B, H, W), aif (B, 3, H, W) or None, std_m (B, H, W), diopters (B, H, W). With `extrapolation`, the
    weight p_0 of the nearest frame is moved e_near end spacings nearer and p_S-1 e_far spacings farther (a bounded
    `extrapolation`: at most EndExtrapolation.FAR_FRACTION of the far frame's diopters farther)."""
    p = softmax_frames(logits)
    d = (p * focus_diopters).sum(1)
    if extrapolation is not None:
        gap_near = (focus_diopters[:, 0] - focus_diopters[:, 1]).abs()
        gap_far = (focus_diopters[:, -2] - focus_diopters[:, -1]).abs()
        gaps_px = None
        if extrapolation.blur_spacing:
            if defocus_px_per_d is None:
                raise ValueError("focus_map_head: this extrapolation needs defocus_px_per_d")
            k = defocus_px_per_d[:, 0]
            gaps_px = (gap_near * k, gap_far * k)
        e_near, e_far = extrapolation(logits, gaps_px)
        far_move = e_far * gap_far
        if extrapolation.bounded:
            far_move = torch.minimum(far_move, extrapolation.FAR_FRACTION * focus_diopters[:, -1].clamp_min(0.0))
        d = d + p[:, 0] * e_near * gap_near - p[:, -1] * far_move
    depth = 1.0 / d.clamp_min(MIN_DIOPTERS)
    frame_m = 1.0 / focus_diopters.clamp_min(MIN_DIOPTERS)
    var = (p * (frame_m - depth[:, None]) ** 2).sum(1)
    std = torch.sqrt(var.clamp_min(0.0) + 1e-12)
    aif = (p[:, :, None] * stack).sum(1) if stack is not None else None
    return depth, aif, std, d


class ConditionedDFVNet(DFVNet):
    """DFVNet on RGB frames whose per-frame features at /4, /8 (, /16, /32) get a per-pixel bias from the two
    conditioning channels of `focus_channels`: a 1x1 convolution (no padding) of the channels average-pooled to that
    scale (fixed windows, exact at every H, W that are multiples of 32). forward(stack (B, S, 3, H, W), dk (B, S, H,
    W), lk (B, 1, H, W)), dk and lk from `cond_inputs`."""

    def __init__(self, cfg: DFVNetConfig, cond_channels: int):
        super().__init__(cfg, in_channels=3)
        if cond_channels != EXTRA_CHANNELS:
            raise ValueError(f"ConditionedDFVNet: {EXTRA_CHANNELS} conditioning channels (focus_channels), got "
                             f"{cond_channels}")
        feats = tuple(reversed(cfg.features))  # /4, /8, /16, /32
        self.cond = nn.ModuleList(nn.Conv2d(cond_channels, feats[i], 1) for i in range(cfg.levels))

    def forward(self, stack: Tensor, dk: Tensor, lk: Tensor) -> list[Tensor]:
        b, s, c, h, w = stack.shape
        feats = self.encoder(stack.reshape(b * s, c, h, w))
        dk = dk.reshape(b * s, 1, h, w)
        for i, proj in enumerate(self.cond):
            f = 4 if i == 0 else 2  # a 2x2 mean of 4x4-window means is the 8x8-window mean (H, W multiples of 32)
            dk, lk = F.avg_pool2d(dk, f, f), F.avg_pool2d(lk, f, f)
            feats[i] = cond_bias(feats[i], proj, dk, lk, b, s)
        return self.decode(feats, b, s)


def cond_bias(feat: Tensor, proj: nn.Conv2d, dk: Tensor, lk: Tensor, b: int, s: int) -> Tensor:
    """feat (B*S, C, h, w) + proj(pooled focus_channels), from D_s k pooled (B*S, 1, h, w) and log2(k) / 4 pooled
    (B, 1, h, w). The same sum in a cheaper order: the pooled blur position is pool(D k) - mean_s pool(D k), over 16
    (pooling and the mean over frames are linear, so they commute), and the log2(k) channel, equal in every frame, is
    projected once per pixel instead of once per frame; nothing is computed at full resolution but D k and its
    pooling (the first export computed both channels of every frame at full resolution)."""
    h, w = dk.shape[-2:]
    pk = dk.reshape(b, s, 1, h, w)
    pos = (pk - pk.mean(1, keepdim=True)).reshape(b * s, 1, h, w)
    per_frame = F.conv2d(pos, proj.weight[:, :1] / 16.0)  # (B*S, C, h, w)
    per_pixel = F.conv2d(lk, proj.weight[:, 1:], proj.bias)  # (B, C, h, w), every frame's
    c = per_frame.shape[1]
    out = (feat + per_frame).reshape(b, s, c, h, w) + per_pixel[:, None]
    return out.reshape(b * s, c, h, w)


class FocusMapDfF(nn.Module):
    """forward(stack (B, S, 3, H, W), focus_diopters (B, S, H, W), defocus_px_per_d (B, 1, H, W)) ->
    (depth_m (B, H, W), aif (B, 3, H, W), std_m (B, H, W)); frames sorted near -> far, H and W multiples of
    `size_multiple`. With all_levels: [(depth_m, aif, std_m, diopters), ...] finest first (training)."""

    name = NET_NAME
    field_channels = 0
    HEAD_PREFIX = "extrap."  # the "_x", "_xb" and "_xbk" sizes' tensors beyond the base size's (training.nets.warm_start)

    def __init__(self, size: str = "small"):
        super().__init__()
        self.size = size
        self.net = ConditionedDFVNet(CONFIGS[base_size(size)], EXTRA_CHANNELS)
        self.size_multiple = int(self.net.size_multiple)
        head = head_of(size)
        self.extrap = (EndExtrapolation(bounded=head != EXTRAPOLATING, blur_spacing=head == BOUNDED_BLUR) if head
                       else None)

    @property
    def n_params(self) -> int:
        return count_params(self)

    def levels(self, stack: Tensor, focus_diopters: Tensor, defocus_px_per_d: Tensor) -> list[tuple]:
        dk, lk = (t.to(stack.dtype) for t in cond_inputs(focus_diopters, defocus_px_per_d))
        return [focus_map_head(lg, stack if i == 0 else None, focus_diopters, self.extrap, defocus_px_per_d)
                for i, lg in enumerate(self.net(stack, dk, lk))]

    def forward(self, stack: Tensor, focus_diopters: Tensor, defocus_px_per_d: Tensor, all_levels: bool = False):
        levels = self.levels(stack, focus_diopters, defocus_px_per_d)
        if all_levels:
            return levels
        depth, aif, std, _ = levels[0]
        return depth, aif, std


def sort_near_to_far(stack: Tensor, focus_diopters: Tensor) -> tuple[Tensor, Tensor]:
    """Frames reordered by descending mean in-focus diopters (near -> far)."""
    order = torch.argsort(focus_diopters.mean((2, 3)), dim=1, descending=True)
    st = torch.gather(stack, 1, order[:, :, None, None, None].expand_as(stack))
    fd = torch.gather(focus_diopters, 1, order[:, :, None, None].expand_as(focus_diopters))
    return st, fd


def _pad(x: Tensor, m: int) -> tuple[Tensor, tuple[int, int]]:
    """(..., H, W) reflect-padded at the bottom/right to multiples of m (replicate where reflect cannot)."""
    h, w = x.shape[-2:]
    ph, pw = (-h) % m, (-w) % m
    if not (ph or pw):
        return x, (h, w)
    lead = x.shape[:-2]
    flat = x.reshape(-1, 1, h, w)
    flat = F.pad(flat, (0, pw, 0, ph), mode="reflect" if ph < h and pw < w else "replicate")
    return flat.reshape(*lead, h + ph, w + pw), (h, w)


def train_levels(module: nn.Module, batch: dict) -> list[tuple]:
    """Training forward of a FocusMapDfF (or its DDP wrapper) on a batch of `training.data.anycam`: sorted,
    padded, every level cropped back. Returns [(depth_m, aif, std_m, diopters), ...] finest first."""
    stack, fd = sort_near_to_far(batch["stack"].float(), batch["focus_diopters"].float())
    m = 32
    stack_p, (h, w) = _pad(stack, m)
    fd_p, _ = _pad(fd, m)
    k_p, _ = _pad(batch["defocus_px_per_d"].float(), m)
    levels = module(stack_p, fd_p, k_p, all_levels=True)
    return [tuple(None if t is None else t[..., :h, :w] for t in lv) for lv in levels]


@torch.no_grad()
def predict(model: FocusMapDfF, stack: Tensor, focus_diopters: Tensor, defocus_px_per_d: Tensor) -> dict:
    """Any stack: frames sorted, H, W padded and cropped back. stack (B, S, 3, H, W) normalised, focus_diopters
    (B, S, H, W), defocus_px_per_d (B, 1, H, W). Returns {"depth_m", "aif", "std_m", "diopters"}."""
    if stack.shape[1] < 3:
        raise ValueError(f"predict: dfv_aat needs at least 3 frames, got {stack.shape[1]}")
    out = train_levels(model, {"stack": stack, "focus_diopters": focus_diopters,
                               "defocus_px_per_d": defocus_px_per_d})[0]
    return dict(zip(("depth_m", "aif", "std_m", "diopters"), out))


def build(size: str = "small") -> FocusMapDfF:
    return FocusMapDfF(size)
