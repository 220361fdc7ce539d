"""Export a trained run (model.pt or last.pt) to ONNX with the metadata of docs/contracts.md."""

from __future__ import annotations

from pathlib import Path

from aat_deploy.lens.io import load_lens
from training.nets import registry
from training.nets.export import dff_metadata, export_dff_onnx
from training.train.data import resolve_lens_path
from training.train.loop import load_trained


def largest_training_image_px(data: dict) -> int:
    """Side (px) of the largest single scenes an any-camera run trained on: its crops, or its whole renders (a mosaic,
    `training.data.anycam.mosaic`, is four unrelated scenes, not a larger one). The runtime runs the net on tiles of
    this size (aat.tile_px): the first run's net, trained on 128 px images, was 2.4x worse on whole 640 x 480 frames
    than on 128 px tiles, and on RF50 validation stacks 128 px tiles beat 96, 256 and whole frames
    (benchmarks/probes/anycam_tiles.py --split validation)."""
    render = min(data.get("height", 160), data.get("width", 160))
    if data.get("crop_sizes"):  # crops of several sides: the largest (capped to the render)
        return min(int(max(data["crop_sizes"])), render)
    return int(data.get("crop") or render)


def tile_px_for(model, data: dict) -> int:
    """aat.tile_px of an any-camera net: 0 (whole frames) for an edge-value-padded net ("replicate"), whose error
    showed no measurable dependence on the image border (the padding ablation, 12 RF50 validation stacks: whole
    frames 0.954 [0.900, 0.976]x its 128 px tiles, a square amid a mirrored margin 0.993x the square alone;
    benchmarks/probes/anycam_border.py, docs/training.md); otherwise the largest training image
    (`largest_training_image_px`): zero-padded nets read the border as a cue, other paddings are untested."""
    pad = getattr(getattr(getattr(model, "net", None), "cfg", None), "pad_mode", "zeros")
    return 0 if pad == "replicate" else largest_training_image_px(data)


def export_checkpoint(checkpoint, out, *, force: bool = False, extra: dict | None = None,
                      ) -> tuple[dict[str, str], float]:
    """checkpoint: a run's model.pt (or last.pt). Writes `out` (atomic, no overwrite unless force) and returns
    (metadata, the relative ORT-vs-torch difference over three shapes, `training.nets.export.parity`).
    extra: more aat.* metadata keys."""
    from training.train.checkpoint import load

    model, cfg = load_trained(Path(checkpoint))
    # the step the weights are from: a checkpoint chosen before the end (an early stop) is not cfg.steps
    extra = {"checkpoint_step": str(int(load(Path(checkpoint)).get("step", cfg.steps))), **(extra or {})}
    if registry.get(cfg.net).focus_maps:  # the any-camera model: no lens of its own (nets.export.focus_map_metadata)
        from training.data.cameras import K_MAX_PX_PER_D
        from training.nets.export import export_focus_map_onnx, focus_map_metadata

        md = focus_map_metadata(model, effects=["camera_processing"], stack_range=cfg.stack_range,
                                config_hash=cfg.hash(), k_range=(0.3, K_MAX_PX_PER_D),
                                extra={"train_steps": cfg.steps, "config_name": cfg.name,
                                       "tile_px": str(tile_px_for(model, cfg.data)), **extra})
        return md, export_focus_map_onnx(model, out, md, force=force)
    lens = load_lens(resolve_lens_path(cfg.lens))
    md = dff_metadata(model, lens, simulator=cfg.simulator, effects=list(cfg.effects),
                      focus_range_m=cfg.focus_range_m, stack_range=cfg.stack_range, config_hash=cfg.hash(),
                      extra={"train_steps": cfg.steps, "config_name": cfg.name, **extra})
    err = export_dff_onnx(model, out, md, force=force)
    return md, err
