"""Why the chart fit's reported-focus family is weakly split from its field term at phone scale (issue 33): the
constant of the offset family against the field term's radial powers, on tiles made from the phone lens's map.

    python -m benchmarks.probes.family_split [--out results/calibrate_family_split.json]   # ~1 min, no rendering

The field term is zero at the frame centre, so only the tiles near it tell a reported-focus offset from the field
term. With the radial powers (rho^4 .. rho^12, `model.FieldBasis`) a near-constant is almost in their span over the
rest of the field: the constant's variance inflation over the tiles' positions (1 / (1 - R^2) of the constant
regressed on the field term's functions) says how much less the tiles know about it. Then, on tiles of
bench_calibrate's three phone charts made from the phone lens's traced map (each tile's peak where the map has its
object in focus, `phone_observations`) with a known reported-focus offset and Gaussian tile noise: the family BIC
chooses, the offset when that family is fitted, and the model's error at the frame centre; seeds 0-3. The phone's
measured tiles scatter 0.1-0.16 D (SD) inside field radius 0.66 and 0.35-0.49 D outside (BENCHMARKS.md).
"""

from __future__ import annotations

import argparse
import json
from functools import lru_cache
from pathlib import Path

import numpy as np

from aat_deploy.calibrate.model import FieldBasis, Observations, fit_all, fit_model
from aat_deploy.focus.bestfocus import load_json
from benchmarks import RESULTS

ROOT = Path(__file__).resolve().parents[2]
PHONE_MAP = ROOT / "lenses" / "best_focus" / "cellphone_asphere.json"  # traced from the phone lens's prescription
ASPECT = 4 / 3  # its sensor's (5.704 x 4.278 mm)


def rho2(x, y):
    return (ASPECT ** 2 * x ** 2 + y ** 2) / (1 + ASPECT ** 2)


@lru_cache(maxsize=1)
def phone_map():
    return load_json(PHONE_MAP)


def truth(x, y, t):
    """In-focus object diopters at field (x, y) of frames focused on axis at t diopters: the phone lens's traced
    map (best focus ~1 D farther than on axis at radius 0.4, 2.6 D nearer at 0.7 and 7 D at the corner for a frame
    focused at 10 cm)."""
    x, y, t = np.broadcast_arrays(*(np.asarray(v, np.float64) for v in (x, y, t)))
    r = np.sqrt(rho2(x, y)).ravel()
    fm = phone_map()
    out = np.empty(r.size)
    for f in np.unique(t):
        sel = t.ravel() == f
        out[sel] = fm.frame_diopters([1.0 / f], r[sel], calibrated=False)[0]
    return out.reshape(x.shape)


def phone_observations(bias_d: float = 0.0, noise_d: float = 0.05, seed: int = 0) -> Observations:
    """Tiles (24 x 18 per sweep) of three tilted charts at 7, 10 and 18 cm (bench_calibrate's phone setup), each
    tile's focus peak at the frame whose true map has its object in focus (reported = true + bias_d), plus
    Gaussian noise; tiles whose peak lies outside 2-20 D are left out (not bracketed)."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid((np.arange(24) + 0.5) / 12 - 1, 1 - (np.arange(18) + 0.5) / 9)
    r = np.sqrt(rho2(x, y)).ravel()
    f_grid = np.linspace(2.0, 20.0, 1801)
    t_grid = phone_map().frame_diopters(1.0 / f_grid, r, calibrated=False)  # (F, N)
    cols = {k: [] for k in ("x", "y", "reported_d", "object_d", "sweep", "cell")}
    for i, (dist, tilt) in enumerate(((0.07, 0.4), (0.1, -0.3), (0.18, 0.2))):
        obj = (1.0 / (dist * (1 + tilt * 0.3 * x))).ravel()  # a tilted plane: distance grows across the frame
        f = np.array([np.interp(obj[j], t_grid[:, j], f_grid, left=np.nan, right=np.nan) for j in range(r.size)])
        ok = np.isfinite(f)
        rep = f[ok] + bias_d + rng.normal(0, noise_d, int(ok.sum()))
        cols["x"].append(x.ravel()[ok])
        cols["y"].append(y.ravel()[ok])
        cols["reported_d"].append(rep)
        cols["object_d"].append(obj[ok])
        cols["sweep"].append(np.full(int(ok.sum()), i))
        cols["cell"].append(i * 10_000 + np.floor(rep / 1.1).astype(int))  # frames 1.1 D apart
    return Observations(*(np.concatenate(cols[k]) for k in cols), aspect=ASPECT)


def constant_vif(obs: Observations, degree: int, radial: int) -> float:
    """Variance inflation of a constant column against FieldBasis(degree, radial) over the tiles' positions."""
    basis = FieldBasis(degree, radial, obs.aspect).columns(obs.x, obs.y)
    one = np.ones(len(obs.x))
    coef, *_ = np.linalg.lstsq(basis, one, rcond=None)
    r2 = 1.0 - float(np.sum((one - basis @ coef) ** 2)) / len(one)  # uncentred: the constant has no mean to remove
    return 1.0 / max(1.0 - r2, 1e-12)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(RESULTS / "calibrate_family_split.json"))
    a = ap.parse_args(argv)
    obs = phone_observations()
    vif = [{"degree": d, "radial": r, "vif": constant_vif(obs, d, r)} for d, r in ((2, 0), (2, 8), (2, 12), (3, 12))]
    rows = []
    for bias in (0.0, 0.18):
        for noise in (0.05, 0.15, 0.3):
            for seed in range(4):
                o = phone_observations(bias_d=bias, noise_d=noise, seed=seed)
                fit = fit_model(o)
                fam = fit_all(o, fit.degree, fit.focus_degree, radial=fit.radial)
                rows.append({"bias_d": bias, "noise_d": noise, "seed": seed, "family": fit.focus.family,
                             "degree": fit.degree, "radial": fit.radial, "focus_degree": fit.focus_degree,
                             "offset_if_fitted_d": fam["offset"][0].bias_d if "offset" in fam else None,
                             "bic": {k: v[3] for k, v in fam.items()},
                             "centre_error_d": float(fit.predict(0.0, 0.0, 10.0 + bias) - truth(0.0, 0.0, 10.0))})
    from aat_deploy.io.atomic import write_text_atomic

    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(Path(a.out), json.dumps({"vif": vif, "fits": rows}, indent=1))
    print("| field term (degree, radial powers to) | the constant's variance inflation over the tiles |")
    print("|---|---|")
    for v in vif:
        print(f"| {v['degree']}, {v['radial'] or 'none'} | {v['vif']:.1f} |")
    print("\n| offset (D) | tile noise SD (D) | family chosen (4 seeds) | offset if fitted (D) | BIC offset - none | "
          "centre error (D) |")
    print("|---|---|---|---|---|---|")
    for bias in (0.0, 0.18):
        for noise in (0.05, 0.15, 0.3):
            rs = [r for r in rows if r["bias_d"] == bias and r["noise_d"] == noise]
            fams = ", ".join(r["family"] for r in rs)
            off = [r["offset_if_fitted_d"] for r in rs if r["offset_if_fitted_d"] is not None]
            dbic = [r["bic"]["offset"] - r["bic"]["none"] for r in rs if "offset" in r["bic"]]
            ce = [r["centre_error_d"] for r in rs]
            print(f"| {bias:g} | {noise:g} | {fams} | {min(off):+.3f} to {max(off):+.3f} | "
                  f"{min(dbic):+.1f} to {max(dbic):+.1f} | {min(ce):+.3f} to {max(ce):+.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
