"""The resolved configuration of a lens-to-model run (`aat-train --lens ...`), written to DIR/config.json.

Command-line options + a preset (tiny | small | paper) resolve to one plain dict: the lens file and the sensor,
the net, focus range, stack size, effects (names or 'name:key=value' settings, as
`aat_deploy.render.effects.parse` reads them), init weights, and per stage its settings (PSF dataset and fit budget,
training, evaluation). Files given by path (lens, --init, --psf) are recorded with their SHA-256 so that a
changed file is a changed input. Units: mm for sensor sizes, pixels for resolutions and crops, metres from the
sensor plane for distances, minutes for the PSF fit's wall-clock budget.
"""

from __future__ import annotations

import copy
import json
from dataclasses import dataclass, field
from pathlib import Path

from aat_deploy.errors import AatError
from training.chain.hashing import file_sha256
from training.nets import registry

FORMAT = "aat-train-chain-v1"
NET_ALIASES = registry.aliases(chain_only=True)  # --net: "dfv", "dfvnet", "aif", "aifnet" (training.nets.registry)

# Per preset: PSF dataset + fit, training, evaluation. Crops are clipped to the sensor resolution.
PRESETS: dict[str, dict] = {
    "tiny": {  # the test configuration: minutes on 2 cores, the model is not useful
        "psf": {"axis_n": 1500, "axis_rays": 256, "val_n": 128, "val_rays": 512, "fit_minutes": 10 / 60,
                "compiled": False},
        "train": {"crop_hw": [48, 64], "n_items": 8, "val_items": 2, "steps": 4, "batch_size": 2, "lr": 1e-3,
                  "warmup_steps": 0, "checkpoint_every": 2, "log_every": 1, "cell_px": 32},
        "eval": {"n_scenes": 2, "cell_px": 64},
        "stack": 5,
    },
    "small": {  # a usable small model in well under an hour on 2 cores (BENCHMARKS.md)
        "psf": {"axis_n": 20000, "axis_rays": 1024, "val_n": 1024, "val_rays": 4096, "fit_minutes": 3.0,
                "compiled": True},
        "train": {"crop_hw": [128, 128], "n_items": 160, "val_items": 8, "steps": 600, "batch_size": 4,
                  "lr": 1e-3, "warmup_steps": 30, "checkpoint_every": 50, "log_every": 10, "cell_px": 32},
        "eval": {"n_scenes": 4, "cell_px": 64},
        "stack": 8,
    },
    "paper": {  # the shipped RF50 models' scale and the full PSF fit (hours on 2 cores; use torchrun)
        "psf": {"axis_n": 200000, "axis_rays": 2048, "val_n": 4096, "val_rays": 8192, "fit_minutes": 10.0,
                "compiled": True},
        "train": {"crop_hw": [128, 128], "n_items": 384, "val_items": 16, "steps": 1500, "batch_size": 4,
                  "lr": 1e-3, "warmup_steps": 50, "checkpoint_every": 100, "log_every": 10, "cell_px": 32},
        "eval": {"n_scenes": 12, "cell_px": 64},
        "stack": 8,
    },
}
FINE_TUNE_LR_FACTOR = 0.1  # with --init the preset's learning rate is scaled by this (unless --lr)
PSF_NEAR_FACTOR, PSF_FAR_FACTOR = 0.8, 2.0  # surrogate range = focus range widened by these (depth margin)


class ChainConfigError(AatError):
    """A command line that cannot be resolved (one line, names the option)."""


@dataclass
class ChainOptions:
    """What the command line says (None = the default / the preset's value)."""

    lens: str
    out: str
    sensor_mm: tuple[float, float] | None = None
    resolution: tuple[int, int] | None = None
    net: str | None = None
    size: str | None = None
    focus_range_m: tuple[float, float] = (0.5, 10.0)
    stack: int | None = None
    effects: list[str] = field(default_factory=list)
    init: str | None = None
    psf: str | None = None
    preset: str = "small"
    steps: int | None = None
    lr: float | None = None
    baseline: bool = True
    seed: int = 0


def _file_ref(path: str | None, what: str) -> dict | None:
    if path is None:
        return None
    p = Path(path).resolve()
    if not p.is_file():
        raise ChainConfigError(f"{what} {path}: no such file")
    return {"path": str(p), "sha256": file_sha256(p)}


def resolve(opts: ChainOptions) -> dict:
    """The resolved config dict (JSON-ready). Checks option values; the lens itself is read by the lens stage."""
    from aat_deploy.render import effects as fx

    if opts.preset not in PRESETS:
        raise ChainConfigError(f"--preset must be one of {sorted(PRESETS)}, got {opts.preset!r}")
    pre = copy.deepcopy(PRESETS[opts.preset])
    init = _file_ref(opts.init, "--init")
    net, size = opts.net, opts.size
    if init is not None:
        from training.nets.warm_start import InitError, init_kind

        try:
            init_net, init_size = init_kind(init["path"])
        except (InitError, OSError, KeyError, ValueError) as e:
            raise ChainConfigError(f"--init: {e}") from None
        for what, asked, have in (("--net", NET_ALIASES.get(net or init_net), init_net),
                                  ("--size", size or init_size, init_size)):
            if asked != have:
                raise ChainConfigError(f"{what}: --init {opts.init} is a {init_net} {init_size} model")
        net, size = init_net, init_size
    net = NET_ALIASES.get(net or "dfvnet")
    if net is None:
        raise ChainConfigError(f"--net must be one of {', '.join(NET_ALIASES)}, got {opts.net!r}")
    size = size or "small"
    sizes = registry.NETS[net].sizes
    if size not in sizes:
        raise ChainConfigError(f"--size must be one of {sizes}, got {size!r}")
    near, far = (float(v) for v in opts.focus_range_m)
    if not 0 < near < far:
        raise ChainConfigError(f"--focus-range-m must be NEAR,FAR with 0 < NEAR < FAR metres, got {near:g},{far:g}")
    stack = int(opts.stack or pre["stack"])
    if stack < 2:
        raise ChainConfigError(f"--stack must be >= 2 frames, got {stack}")
    effects = []
    for e in opts.effects:
        if effect_name(e) == "aberrations":
            raise ChainConfigError("--effects: 'aberrations' is what the AAT run adds over the thin-lens baseline; "
                                   "list only extra effects")
        try:
            spec = fx.spec(fx.parse([e])[0])  # 'name' or 'name:k=v' (settings that differ from the defaults)
        except (ValueError, TypeError) as err:
            raise ChainConfigError(f"--effects: {err} (known: {', '.join(fx.names())})") from None
        if spec not in effects:
            effects.append(spec)
    if opts.sensor_mm is not None and min(opts.sensor_mm) <= 0:
        raise ChainConfigError(f"--sensor-mm must be positive W,H in mm, got {opts.sensor_mm}")
    if opts.resolution is not None and min(opts.resolution) < 8:
        raise ChainConfigError(f"--resolution must be W,H of at least 8 px, got {opts.resolution}")
    tr = pre["train"]
    if opts.steps is not None:
        if opts.steps < 1:
            raise ChainConfigError(f"--steps must be >= 1, got {opts.steps}")
        tr["steps"] = int(opts.steps)
        tr["warmup_steps"] = min(tr["warmup_steps"], tr["steps"] // 10)
    if init is not None:
        tr["lr"] *= FINE_TUNE_LR_FACTOR
    if opts.lr is not None:
        if opts.lr <= 0:
            raise ChainConfigError(f"--lr must be > 0, got {opts.lr}")
        tr["lr"] = float(opts.lr)
    tr["checkpoint_every"] = min(tr["checkpoint_every"], tr["steps"])
    # A short run (fine-tuning) sees at most steps x batch scenes: render only those (but a few batches' worth).
    tr["n_items"] = min(tr["n_items"], max(tr["steps"] * tr["batch_size"], 8 * tr["batch_size"]))
    psf_ref = _file_ref(opts.psf, "--psf")
    pre["psf"].update({"near_m": near * PSF_NEAR_FACTOR, "far_m": far * PSF_FAR_FACTOR, "kernel_size": 11,
                       "margin_px": 4.0, "wavelength_nm": 589.0, "seed": opts.seed})
    return {
        "format": FORMAT,
        "lens": _file_ref(opts.lens, "--lens"),
        "sensor_mm": None if opts.sensor_mm is None else [float(v) for v in opts.sensor_mm],
        "resolution": None if opts.resolution is None else [int(v) for v in opts.resolution],
        "net": net,
        "size": size,
        "preset": opts.preset,
        "focus_range_m": [near, far],
        "stack": stack,
        "effects": effects,
        "init": init,
        "psf_file": psf_ref,
        "baseline": bool(opts.baseline),
        "seed": int(opts.seed),
        "psf": pre["psf"],
        "train": tr,
        "eval": pre["eval"],
    }


def effect_name(spec: str) -> str:
    """'noise:full_well_e=3000' -> 'noise'."""
    return spec.split(":", 1)[0].strip()


def differences(old: dict, new: dict, prefix: str = "") -> list[str]:
    """Dotted keys whose values differ between two resolved configs."""
    out = []
    for k in sorted(set(old) | set(new)):
        a, b = old.get(k), new.get(k)
        if isinstance(a, dict) and isinstance(b, dict):
            out += differences(a, b, f"{prefix}{k}.")
        elif a != b:
            out.append(f"{prefix}{k}")
    return out


def load(path) -> dict | None:
    p = Path(path)
    if not p.is_file():
        return None
    try:
        return json.loads(p.read_text())
    except json.JSONDecodeError:
        return None
