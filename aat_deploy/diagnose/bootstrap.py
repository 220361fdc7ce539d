"""The diagnosis's intervals, under the names it has used: they are `aat_deploy.eval.stats`'s (one implementation).
`capture_bootstrap` is `bootstrap_mean` over captures. Kept until the diagnosis is split (issue 36, phase B-2)."""

from aat_deploy.eval.stats import TILE_PX, BinnedStats, binned_bootstrap, ratio_bootstrap, unit_sums
from aat_deploy.eval.stats import bootstrap_mean as capture_bootstrap

__all__ = ["TILE_PX", "BinnedStats", "binned_bootstrap", "capture_bootstrap", "ratio_bootstrap", "unit_sums"]
