"""Training configuration: a dataclass loaded from JSON (`configs/dff_*.json`), validated with one-line errors.

`data` / `val_data` are passed through to the dataset config of `training.data.stacks` (see
`training.train.data.make_dataset`); `simulator` ("aat" | "thin_lens") and `lens` are set on it by the loop,
so the two simulators differ only in that field.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from aat_deploy.errors import AatError
from training.nets import registry
from training.nets.export import config_hash

SIMULATORS = ("aat", "thin_lens", "any_camera")  # any_camera: the data of nets with focus maps (training.data.anycam)


class ConfigError(AatError):
    pass


@dataclass
class LossConfig:
    """Weights of the loss terms. depth: L1 on depth over valid ground truth (the paper's loss). aif: L1 on the
    all-in-focus image. smooth: edge-aware Charbonnier smoothness of depth (weights exp(-smooth_edge |grad I|)).
    level_weights: per output level, finest first (DFVNet's deep supervision; missing levels get 0).
    mask_focus_range: also mask ground truth outside each stack's focus range (for the dfvaat net only in its
    validation: its loss scores every pixel, training.train.loss.focus_map_loss). out_of_range_weight (the dfvaat
    net's loss only): the weight of pixels whose true diopters lie outside their own frames' range, which no
    interpolation of the frames can reach (1: every pixel alike, as the first five any-camera runs; 0: left out)."""

    depth: float = 1.0
    aif: float = 0.0
    smooth: float = 0.0
    smooth_edge: float = 150.0
    level_weights: tuple[float, ...] = (1.0,)
    mask_focus_range: bool = False
    depth_space: str = "m"  # "m": L1 on depth in metres (the paper's); "diopter": L1 on inverse depth (1/m)
    out_of_range_weight: float = 1.0


@dataclass
class TrainConfig:
    name: str
    net: str  # a net of training.nets.registry: "aifnet" | "dfvnet" | "dfvaat"
    size: str  # one of the net's sizes: "small" | "full"
    simulator: str  # "aat" | "thin_lens" | "any_camera"
    lens: str  # lens file (path relative to the repository root or absolute)
    data: dict = field(default_factory=dict)
    val_data: dict | None = None
    effects: list[str] = field(default_factory=list)
    focus_range_m: tuple[float, float] = (0.5, 10.0)  # for the export metadata
    stack_range: tuple[int, int] = (2, 16)  # stack sizes the exported model is declared for
    steps: int = 1000  # optimizer steps (global); the cosine schedule spans exactly these
    batch_size: int = 2  # per process
    lr: float = 1e-4
    lr_min: float = 0.0
    warmup_steps: int = 0
    weight_decay: float = 0.0
    grad_clip: float = 1.0  # max global grad norm; 0 = off
    loss: LossConfig = field(default_factory=LossConfig)
    num_workers: int = 0
    seed: int = 0
    checkpoint_every: int = 50
    log_every: int = 10
    val_every: int = 0  # 0 = only at the end
    val_items: int = 16
    field_channels: int = 0  # 2: the nets also see each pixel's normalised sensor position (training.nets.model)
    init: str | None = None  # weights to start from: an exported DfF .onnx or a model.pt/last.pt (training.nets.warm_start)
    train_only: str = ""  # a parameter-name prefix: only those train, the rest is frozen (training.train.loop.freeze_all_but)

    def validate(self) -> TrainConfig:
        net = registry.NETS.get(self.net)
        if net is None:
            raise ConfigError(f"config {self.name}: net must be one of {tuple(registry.NETS)}, got {self.net!r}")
        if net.focus_maps != (self.simulator == "any_camera"):
            maps = [n.name for n in registry.NETS.values() if n.focus_maps]
            raise ConfigError(f"config {self.name}: net {' / '.join(maps)} goes with simulator any_camera (its own "
                              "data), and only it")
        if self.size not in net.sizes:
            raise ConfigError(f"config {self.name}: size must be one of {net.sizes}, got {self.size!r}")
        if self.simulator not in SIMULATORS:
            raise ConfigError(f"config {self.name}: simulator must be one of {SIMULATORS}, got {self.simulator!r}")
        if self.steps < 1 or self.batch_size < 1:
            raise ConfigError(f"config {self.name}: steps and batch_size must be >= 1")
        if not 0 <= self.lr_min <= self.lr:
            raise ConfigError(f"config {self.name}: need 0 <= lr_min <= lr")
        if not 0 < self.focus_range_m[0] < self.focus_range_m[1]:
            raise ConfigError(f"config {self.name}: focus_range_m must be [near, far] with 0 < near < far")
        if not 2 <= self.stack_range[0] <= self.stack_range[1]:
            raise ConfigError(f"config {self.name}: stack_range must be [min, max] with 2 <= min <= max")
        if self.field_channels not in net.field_channels:
            raise ConfigError(f"config {self.name}: field_channels must be one of {net.field_channels}")
        if self.loss.depth_space not in ("m", "diopter"):
            raise ConfigError(f"config {self.name}: loss.depth_space must be 'm' or 'diopter'")
        if not 0.0 <= self.loss.out_of_range_weight <= 1.0:
            raise ConfigError(f"config {self.name}: loss.out_of_range_weight must be within [0, 1]")
        if not self.loss.level_weights or sum(self.loss.level_weights) <= 0:
            raise ConfigError(f"config {self.name}: loss.level_weights must have a positive sum")
        return self

    def to_dict(self) -> dict:
        return asdict(self)

    def hash(self) -> str:
        """Hash of everything that defines the trained model (not logging / checkpoint cadence)."""
        d = self.to_dict()
        for k in ("checkpoint_every", "log_every", "val_every", "val_items", "num_workers"):
            d.pop(k)
        if d.get("init") is None:
            d.pop("init")  # configs without an init hash as they did before the field existed
        if not d.get("train_only"):
            d.pop("train_only")  # configs without it hash as they did before the field existed
        if not d.get("field_channels"):
            d.pop("field_channels")  # likewise
        if d["loss"].get("depth_space") == "m":
            d["loss"].pop("depth_space")  # likewise
        if d["loss"].get("out_of_range_weight") == 1.0:
            d["loss"].pop("out_of_range_weight")  # likewise
        return config_hash(d)


def config_from_dict(d: dict, where: str = "<dict>") -> TrainConfig:
    known = {f.name for f in fields(TrainConfig)}
    unknown = sorted(set(d) - known - {"comment"})
    if unknown:
        raise ConfigError(f"{where}: unknown config keys {unknown}")
    d = {k: v for k, v in d.items() if k != "comment"}
    loss = d.pop("loss", {}) or {}
    lknown = {f.name for f in fields(LossConfig)}
    if set(loss) - lknown:
        raise ConfigError(f"{where}: unknown loss keys {sorted(set(loss) - lknown)}")
    if "level_weights" in loss:
        loss["level_weights"] = tuple(float(x) for x in loss["level_weights"])
    for k in ("focus_range_m", "stack_range"):
        if k in d:
            d[k] = tuple(d[k])
    missing = [k for k in ("name", "net", "size", "simulator", "lens") if k not in d]
    if missing:
        raise ConfigError(f"{where}: missing config keys {missing}")
    try:
        cfg = TrainConfig(**d, loss=LossConfig(**loss))
    except TypeError as e:
        raise ConfigError(f"{where}: {e}") from None
    return cfg.validate()


def load_config(path) -> TrainConfig:
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such config file") from None
    except json.JSONDecodeError as e:
        raise ConfigError(f"{path}: invalid JSON ({e})") from None
    return config_from_dict(d, str(path))
