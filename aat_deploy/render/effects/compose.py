"""Effects together: a list of effects applied hook by hook, in the effects' order (lowest `order` first), to a PSF
source, the focus, a rendered frame or a whole stack."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .base import Effect, SimContext


def wrap_source(effects: list[Effect], source, ctx: SimContext):
    """The PSF source seen through every effect's `wrap_source`, in the effects' order (lowest first)."""
    for e in sorted(effects, key=lambda e: e.order):
        source = e.wrap_source(source, ctx)
    return source


def varies_focus(effects: list[Effect]) -> bool:
    """True when one of the effects makes focus vary over the field (a `focus_at` or `sensor_shift_mm` hook)."""
    return any(type(e).focus_at is not Effect.focus_at or type(e).sensor_shift_mm is not Effect.sensor_shift_mm
               for e in effects)


def focus_at(effects: list[Effect], ctx: SimContext) -> Callable | None:
    """The per-field focus function of the effects (None: focus is the same everywhere): the first effect's
    `focus_at` if one has it, else the sum of their sensor shifts (`sensor_shift_mm`) through the lens's focus
    table: focus(x, y) = 1 / diopters(z(focus_m) + sum of shifts), z clipped to the table."""
    effects = sorted(effects, key=lambda e: e.order)
    first = next((f for f in (e.focus_at(ctx) for e in effects) if f is not None), None)
    shifts = [f for f in (e.sensor_shift_mm(ctx) for e in effects) if f is not None]
    if first is not None or not shifts:
        return first
    table = ctx.focus_table()

    def fn(x, y, focus_m):
        z = float(table(focus_m)) + sum(np.asarray(f(x, y, focus_m), np.float64) for f in shifts)
        z = np.clip(z, table.sensor_z_mm[0], table.sensor_z_mm[-1])  # ascending in z with diopters
        return 1.0 / np.interp(z, table.sensor_z_mm, table.diopters)

    return fn


def twin_focus(effects: list[Effect], focus_reported_m, ctx: SimContext, rng: np.random.Generator) -> np.ndarray:
    """True focus distances (m) for a digital twin that knows only the reported ones."""
    focus = np.asarray(focus_reported_m, dtype=np.float64).ravel()
    for e in sorted(effects, key=lambda e: e.order):
        focus = e.twin_focus(focus, ctx, rng)
    return focus


def post_frame(effects: list[Effect], frame: np.ndarray, focus_m: float, ctx: SimContext,
               rng: np.random.Generator) -> np.ndarray:
    """One rendered frame (C, H, W), numpy, through the effects' geometry (`warp`) then sensor (`sensor`) hooks
    (effects with a `stack` hook need the whole stack: `post_stack`)."""
    effects = sorted(effects, key=lambda e: e.order)
    for e in effects:
        frame = e.warp(frame, focus_m, ctx)
    for e in effects:
        frame = e.sensor(frame, ctx, rng)
    return frame


def post_stack(effects: list[Effect], frames, focus_m, ctx: SimContext, rng: np.random.Generator) -> np.ndarray:
    """Rendered frames (S, C, H, W), numpy, through the warps (frame by frame), the `stack` hooks (the whole stack)
    and the sensor hooks (frame by frame, in order: the same random draws as `post_frame` frame after frame when
    no effect has a `stack` hook)."""
    effects = sorted(effects, key=lambda e: e.order)
    focus = np.asarray(focus_m, np.float64).ravel()
    out = [fr for fr in frames]
    for i, f in enumerate(focus):
        for e in effects:
            out[i] = e.warp(out[i], float(f), ctx)
    stacked = [e for e in effects if type(e).stack is not Effect.stack]
    if stacked:
        arr = np.stack(out)
        for e in stacked:
            arr = e.stack(arr, focus, ctx, rng)
        out = list(arr)
    for i in range(len(out)):
        for e in effects:
            out[i] = e.sensor(out[i], ctx, rng)
    return np.stack(out)
