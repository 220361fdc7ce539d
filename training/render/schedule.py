"""Focus schedules like a camera's: a fixed set of focus distances, chosen from the lens and the working range,
never from the scene's depth.

Distances are metres from the sensor plane, returned sorted near -> far (DfF nets expect frames sorted by
focus). Spacing is even in diopters, where defocus blur is linear. Training may jitter each distance by a small
amount in diopters (and keep the order); evaluation uses the fixed set.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FocusSchedule:
    near_m: float = 0.5
    far_m: float = 5.0
    n: int = 8
    jitter_d: float = 0.0  # training only: uniform jitter in diopters, as a fraction of the spacing below

    def __post_init__(self):
        if not (0 < self.near_m < self.far_m):
            raise ValueError(f"focus schedule needs 0 < near_m < far_m, got {self.near_m}, {self.far_m}")
        if self.n < 2:
            raise ValueError(f"focus schedule needs at least 2 frames, got {self.n}")
        if not 0.0 <= self.jitter_d < 0.5:
            raise ValueError("jitter_d must be in [0, 0.5) of the diopter spacing (keeps the order)")

    @property
    def spacing_d(self) -> float:
        return (1.0 / self.near_m - 1.0 / self.far_m) / (self.n - 1)

    def distances(self, rng: np.random.Generator | None = None) -> np.ndarray:
        """Focus distances (m), near -> far. With `rng` and jitter_d > 0: jittered (training)."""
        inv = np.linspace(1.0 / self.near_m, 1.0 / self.far_m, self.n)
        if rng is not None and self.jitter_d > 0:
            inv = inv + rng.uniform(-1, 1, self.n) * self.jitter_d * self.spacing_d
            inv = np.clip(inv, 1.0 / self.far_m * 0.5, None)
        return 1.0 / inv
