"""Focus schedules like a camera's: a fixed set of focus distances, chosen from the lens and the working range,
never from the scene's depth; and, for comparison with the paper, its protocol, which spreads the distances over
each image's own depth range (`scene_range_distances`: ground truth chooses the focus distances).

Distances are metres from the sensor plane, returned sorted near -> far (DfF nets expect frames sorted by
focus). Spacing is even in diopters, where defocus blur is linear. Training may jitter each distance by a small
amount in diopters (and keep the order); evaluation uses the fixed set.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aat_deploy.optics.focus_table import even_diopters


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
        inv = even_diopters(self.near_m, self.far_m, self.n)
        if rng is not None and self.jitter_d > 0:
            inv = inv + rng.uniform(-1, 1, self.n) * self.jitter_d * self.spacing_d
            inv = np.clip(inv, 1.0 / self.far_m * 0.5, None)
        return 1.0 / inv


def scene_range_distances(depth_m: np.ndarray, n: int, rng: np.random.Generator | None = None,
                          perturb: float = 0.25) -> np.ndarray:
    """The paper's protocol (Yang et al. 2023, Sec. 5.1): n focus distances (m) linear in depth from the minimum
    to the maximum valid depth of this image, each moved by a uniform random perturbation of up to `perturb` of
    the spacing (with `rng`), sorted near -> far. It reads the ground truth, so results under it are labelled so."""
    d = np.asarray(depth_m, dtype=np.float64)
    d = d[np.isfinite(d) & (d > 0)]
    if d.size == 0:
        raise ValueError("scene_range_distances: no valid depth")
    lo, hi = float(d.min()), float(d.max())
    if hi <= lo * 1.001:
        hi = lo * 1.05  # a flat scene still gets distinct focus distances
    out = np.linspace(lo, hi, n)
    if rng is not None and perturb > 0:
        step = (hi - lo) / (n - 1)
        out = out + rng.uniform(-perturb, perturb, n) * step
    return np.sort(np.clip(out, 0.5 * lo, None))
