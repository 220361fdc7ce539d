"""Blind calibration from ordinary scene stacks, no chart (`aat-calibrate fit --from-scenes`): the field term under
which the captures' per-pixel focus estimates agree where they see the same surface.

Between captures the camera turns (panning on a tripod, or by hand about the lens): the same point is then seen at
two field positions. Its distance from the lens's pupil (its range) does not change, so the diopters the two
captures measure for it must agree once each is read through the camera's field term: where a tilted sensor or a
decentred element makes the right side of the field focus nearer, a point moving from the left to the right of the
frame seems to move nearer in the raw estimates, by exactly the field term's difference. Many such pairs over many
captures pin the field term down (up to its value at the centre, which is the reported focus's own).

Steps: per capture, the classical method's per-pixel in-focus estimate in reported diopters (no filling) with its
confidence and all-in-focus image (`aat_deploy.focus`); per pair of captures, ORB features on the all-in-focus
images and a RANSAC homography (a turning camera's views are related by one, whatever the depth); samples on a
grid of confident pixels of one capture, mapped into the other; per pair of samples the relation of a turning
pinhole: z = rho cos(theta), with theta the ray's angle from the axis (focal length in pixels from EXIF and
--sensor-mm, else fitted to the homographies); a least-squares fit of the field term (the chart fit's polynomial,
`model.py`) with robust weights; a bootstrap over the captures.

The field term is a polynomial of degree 2 by default (tilt, the linear part of a decentre, the quadratic field
curvature): the samples are noisy (about 0.1 D each on an 8-frame stack) and higher orders followed the noise in
the test's views (degree 4 missed a vertical tilt by 21 %, degree 2 by 7 %); the chart resolves more. It is fitted constant in focus by default (`focus_degree` 0): how it changes with focus (a tilt's
diopters grow towards far focus, ~15 % between 0.7 and 1.5 m on a 50 mm lens) is weakly determined by scenes
(a linear term fitted on the test's views moved the near end the wrong way); the chart fit resolves it.

Captures that all turn one way (every pair's points move along one line) are refused (`turn_spread`): a field
term that changes only across that line is invisible to them. A field term whose bootstrap spread over the captures
exceeds a tenth of the stacks' frame spacing is warned about and the spread recorded (`spread_check`).

What it cannot identify, and keeps from the reported focus: a common offset of every frame's focus (it moves every
estimate alike; one known distance measures it: a chart sweep) and a common scale of the focus distances (a scene
twice as far, focused twice as far, looks the same). The reported-focus error is therefore `none` in the file,
with a note; combine with one chart sweep, or give --focus-scale if you know it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..focus.method import FocusConfig, classical_depth
from .format import CameraCalibration, CameraIdentity, FieldPoly, FocusError, poly_terms

MIN_INLIERS = 40
SAMPLE_PX = 8  # samples on a grid of this spacing (px at the working size)
MIN_CONFIDENCE = 0.5
NOT_IDENTIFIED = ("a common offset of every frame's focus (needs one known distance) and a common scale of the "
                  "focus distances: the reported focus is kept for both")


@dataclass
class SceneEstimate:
    """One capture: diopters (H, W) per-pixel in-focus estimate in reported diopters, confidence (H, W), aif_u8
    (H, W) grey for matching, reported_d (S,), name."""

    name: str
    diopters: np.ndarray
    confidence: np.ndarray
    aif_u8: np.ndarray
    reported_d: np.ndarray


BLIND_CONFIG = FocusConfig(estimator="gauss", fill="none")  # gauss: its estimates follow a shift of the true
# peak more nearly one to one than the ratio estimator's on an 8-frame schedule (tilt 7 % low, against 15 % high)


def estimate_scene(name: str, frames: np.ndarray, reported_m: np.ndarray,
                   config: FocusConfig = BLIND_CONFIG) -> SceneEstimate:
    """frames (S, 3, H, W) linear, any order; reported_m (S,) the metadata's focus distances."""
    from .pose import to_u8

    res = classical_depth(frames, reported_m, config=config)
    return SceneEstimate(name, res.diopters.astype(np.float64), res.confidence, to_u8(res.aif),
                         np.sort(1.0 / np.asarray(reported_m, np.float64)))


@dataclass
class Pairs:
    """Sample pairs: field positions xa, ya, xb, yb; reported-diopter estimates da, db; cos_a, cos_b of the rays'
    angles from the axis; weight; capture indices ia, ib."""

    xa: np.ndarray
    ya: np.ndarray
    xb: np.ndarray
    yb: np.ndarray
    da: np.ndarray
    db: np.ndarray
    cos_a: np.ndarray
    cos_b: np.ndarray
    weight: np.ndarray
    ia: np.ndarray
    ib: np.ndarray
    homographies: list = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.xa)


def homography(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray | None, int]:
    """(H mapping a's pixels to b's, inliers) from ORB matches on two grey uint8 images, or (None, n)."""
    orb = cv2.ORB_create(4000)
    ka, da = orb.detectAndCompute(a, None)
    kb, db = orb.detectAndCompute(b, None)
    if da is None or db is None or len(ka) < MIN_INLIERS or len(kb) < MIN_INLIERS:
        return None, 0
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(da, db)
    if len(matches) < MIN_INLIERS:
        return None, len(matches)
    pa = np.float32([ka[m.queryIdx].pt for m in matches])
    pb = np.float32([kb[m.trainIdx].pt for m in matches])
    h, inl = cv2.findHomography(pa, pb, cv2.RANSAC, 2.0)
    n = int(inl.sum()) if inl is not None else 0
    return (h if h is not None and n >= MIN_INLIERS else None), n


def focal_from_homographies(hs: list[np.ndarray], width: int, height: int) -> float:
    """The focal length (px) under which the homographies are closest to rotations (K^-1 H K orthogonal up to
    scale), principal point at the centre; a 1-D search over 0.3..5 x the width."""
    if not hs:
        return math.nan
    c = np.array([[1, 0, (width - 1) / 2], [0, 1, (height - 1) / 2], [0, 0, 1]])

    def cost(f):
        k = c @ np.diag([f, f, 1.0])
        ki = np.linalg.inv(k)
        total = 0.0
        for h in hs:
            m = ki @ h @ k
            m = m / np.cbrt(np.linalg.det(m))
            total += float(np.sum((m @ m.T - np.eye(3)) ** 2))
        return total

    fs = np.geomspace(0.3 * width, 5 * width, 200)
    i = int(np.argmin([cost(f) for f in fs]))
    fine = np.geomspace(fs[max(i - 1, 0)], fs[min(i + 1, len(fs) - 1)], 60)
    return float(fine[int(np.argmin([cost(f) for f in fine]))])


def pair_samples(scenes: list[SceneEstimate], f_px: float | None = None, progress=None) -> Pairs:
    """Samples of every pair of captures that see the same surface (a homography with >= MIN_INLIERS)."""
    h, w = scenes[0].diopters.shape
    found = []
    for i in range(len(scenes)):
        for j in range(i + 1, len(scenes)):
            hm, n = homography(scenes[i].aif_u8, scenes[j].aif_u8)
            if hm is not None:
                found.append((i, j, hm))
        if progress:
            progress(i + 1, len(scenes))
    if f_px is None or not math.isfinite(f_px):
        f_px = focal_from_homographies([hm for _, _, hm in found], w, h)
    cx, cy = (w - 1) / 2, (h - 1) / 2
    vv, uu = np.mgrid[SAMPLE_PX // 2:h:SAMPLE_PX, SAMPLE_PX // 2:w:SAMPLE_PX]
    pts = np.stack([uu.ravel(), vv.ravel()], 1).astype(np.float64)
    cols = {k: [] for k in ("xa", "ya", "xb", "yb", "da", "db", "cos_a", "cos_b", "weight", "ia", "ib")}
    for i, j, hm in found:
        for a, b, hab in ((i, j, hm), (j, i, np.linalg.inv(hm))):  # both ways: samples on each one's own grid
            sa, sb = scenes[a], scenes[b]
            q = cv2.perspectiveTransform(pts.reshape(-1, 1, 2), hab).reshape(-1, 2)
            ub, vb = np.round(q[:, 0]).astype(int), np.round(q[:, 1]).astype(int)
            inside = (ub >= 0) & (ub < w) & (vb >= 0) & (vb < h)
            ua, va = pts[inside, 0].astype(int), pts[inside, 1].astype(int)
            ub, vb = ub[inside], vb[inside]
            ca, cb = sa.confidence[va, ua], sb.confidence[vb, ub]
            ok = (ca > MIN_CONFIDENCE) & (cb > MIN_CONFIDENCE) & np.isfinite(sa.diopters[va, ua]) \
                & np.isfinite(sb.diopters[vb, ub])
            ua, va, ub, vb = ua[ok], va[ok], ub[ok], vb[ok]
            cols["xa"].append(2 * (ua + 0.5) / w - 1)
            cols["ya"].append(1 - 2 * (va + 0.5) / h)
            cols["xb"].append(2 * (ub + 0.5) / w - 1)
            cols["yb"].append(1 - 2 * (vb + 0.5) / h)
            cols["da"].append(sa.diopters[va, ua])
            cols["db"].append(sb.diopters[vb, ub])
            cols["cos_a"].append(1 / np.sqrt(1 + ((ua - cx) ** 2 + (va - cy) ** 2) / f_px ** 2))
            cols["cos_b"].append(1 / np.sqrt(1 + ((ub - cx) ** 2 + (vb - cy) ** 2) / f_px ** 2))
            cols["weight"].append(np.minimum(ca[ok], cb[ok]).astype(np.float64))
            cols["ia"].append(np.full(len(ua), a))
            cols["ib"].append(np.full(len(ua), b))
    arrays = {k: (np.concatenate(v) if v else np.zeros(0)) for k, v in cols.items()}
    out = Pairs(**arrays, homographies=[(i, j, hm) for i, j, hm in found])
    out.f_px = f_px
    return out


def _through(d_b: np.ndarray, c: np.ndarray, pupil_m: float) -> tuple[np.ndarray, np.ndarray]:
    """h(D_b): the diopters capture a sees for a point capture b sees at D_b (same range, c = cos_a / cos_b,
    distances from the sensor = pupil z + pupil_m) and dh/dD_b."""
    z_b = 1.0 / d_b - pupil_m
    z_a = z_b * c
    h = 1.0 / (z_a + pupil_m)
    return h, c * h * h / (d_b * d_b)


def fit_field(p: Pairs, degree: int = 4, pupil_m: float = 0.0, weight: np.ndarray | None = None,
              iterations: int = 3, focus_degree: int = 1, focus_range_d: tuple[float, float] = (0.0, 1.0)
              ) -> tuple[np.ndarray, np.ndarray]:
    """(coefficients (K, J) of `poly_terms(degree, False)` x Legendre in the focus over focus_range_d, residuals
    (N,)): least squares of D_a + field(a) = h(D_b + field(b)), linearised in the field at D_b, with robust
    reweighting. A sample's focus (the frame that has it sharp) is its own estimate."""
    terms = poly_terms(degree, constant=False)
    fp0 = FieldPoly(terms, np.zeros((len(terms), focus_degree + 1)), focus_range_d)
    leg_a = np.polynomial.legendre.legvander(fp0.tau(p.da), focus_degree)
    leg_b = np.polynomial.legendre.legvander(fp0.tau(p.db), focus_degree)
    phi_a = np.stack([p.xa ** a * p.ya ** b for a, b in terms], 1)
    phi_b = np.stack([p.xb ** a * p.yb ** b for a, b in terms], 1)
    phi_a = (phi_a[:, :, None] * leg_a[:, None, :]).reshape(len(p), -1)
    phi_b = (phi_b[:, :, None] * leg_b[:, None, :]).reshape(len(p), -1)
    c = p.cos_a / p.cos_b
    hb, dh = _through(np.maximum(p.db, 1e-3), c, pupil_m)
    a = phi_a - dh[:, None] * phi_b
    y = hb - p.da
    w0 = p.weight if weight is None else weight
    w = w0.copy()
    coef = np.zeros(phi_a.shape[1])
    for _ in range(iterations):
        sw = np.sqrt(np.maximum(w, 0))
        coef, *_ = np.linalg.lstsq(a * sw[:, None], y * sw, rcond=None)
        res = y - a @ coef
        s = 1.4826 * float(np.median(np.abs(res[w0 > 0]))) + 1e-6
        w = w0 / np.maximum(1.0, np.abs(res) / (2.5 * s))  # Huber
    return coef.reshape(len(terms), focus_degree + 1), y - a @ coef


@dataclass
class BlindResult:
    calibration: CameraCalibration
    pairs: Pairs
    residual_d: np.ndarray
    warnings: list[str] = field(default_factory=list)


MIN_TURN_SPREAD = 0.05  # least ratio of the turns' direction spread (about +-22 deg around one direction)


def turn_spread(p: Pairs) -> float:
    """How many directions the paired samples moved in across the field: the smaller over the larger eigenvalue
    of the mean outer product of their unit displacement (x, y normalised field) directions; 0 when every pair
    moved along one line (the camera turned one way only), 1 when all directions are alike. A field term changing
    only across that line is then invisible: a point seen at (x, y1) and (x, y2) says nothing of how focus
    changes with x."""
    d = np.stack([p.xb - p.xa, p.yb - p.ya], 1)
    n = np.linalg.norm(d, axis=1)
    ok = n > 1e-6
    if not ok.any():
        return 0.0
    u = d[ok] / n[ok, None]
    ev = np.linalg.eigvalsh((u[:, :, None] * u[:, None, :]).mean(0))
    return float(ev[0] / max(ev[1], 1e-12))


SPREAD_FRACTION = 0.1  # the issue's accuracy rule: a tenth of the stacks' frame spacing (0.02-0.03 D on 8 frames)
MIN_BOOT_CAPTURES = 3  # a bootstrap over two captures cannot vary their one pair's samples


def spread_check(sd: np.ndarray, field_d: np.ndarray, scenes: list[SceneEstimate], replicates: int) -> dict:
    """Whether the bootstrap says the field term is determined: sd (ny, nx) its bootstrap SD over captures and
    field_d (ny, nx) the field term (minus its centre value) on the same grid (D). sd_rms_d (RMS of sd over the
    grid) is compared with limit_d, SPREAD_FRACTION of the captures' median frame spacing (reported diopters): the
    accuracy a calibration should have to matter to depth from focus on those stacks. With few captures the
    spread says how much the fit rests on single ones (a replicate without one of three may keep only a one-way
    pair), not its error: a bias common to all captures (the field term's constancy in focus) no bootstrap sees.
    Returns {"sd_rms_d", "field_rms_d", "limit_d", "warning"} (a one-line warning, "" when the spread is within the
    limit), as the calibration file's `uncertainty` records them."""
    steps = np.concatenate([np.diff(np.sort(s.reported_d)) for s in scenes])
    limit = SPREAD_FRACTION * float(np.median(steps[steps > 0])) if (steps > 0).any() else math.nan
    rms = float(np.sqrt(np.mean(sd ** 2))) if replicates > 1 else math.nan
    field_rms = float(np.sqrt(np.mean(field_d ** 2)))
    fin = lambda v: round(v, 6) if math.isfinite(v) else None  # the file is strict JSON
    out = {"sd_rms_d": fin(rms), "field_rms_d": fin(field_rms), "limit_d": fin(limit), "warning": ""}
    if len(scenes) < MIN_BOOT_CAPTURES or not math.isfinite(rms):
        out["warning"] = (f"the field term's spread cannot be measured from {len(scenes)} captures (a bootstrap over "
                          f"captures needs {MIN_BOOT_CAPTURES} or more): its accuracy is unknown; add captures")
    elif rms > limit:
        out["warning"] = (f"the field term is poorly determined: its bootstrap SD over the captures is {rms:.3f} D "
                          f"RMS over the field, above {limit:.3f} D (a tenth of the stacks' frame spacing), against a "
                          f"field term of {field_rms:.3f} D RMS: it rests on single captures; add captures turned "
                          "both ways")
    return out


def fit_from_scenes(scenes: list[SceneEstimate], identity: CameraIdentity, size_px: tuple[int, int],
                    sensor_mm=None, pupil_mm: float | None = None, degree: int = 2, focus_degree: int = 0,
                    n_boot: int = 50, progress=None, settings: dict | None = None) -> BlindResult:
    """The calibration (field term; reported focus kept) from scene estimates of one camera."""
    h, w = scenes[0].diopters.shape
    f_px = None
    if identity.focal_length_mm and sensor_mm:
        f_px = identity.focal_length_mm / (sensor_mm[0] / w)
    p = pair_samples(scenes, f_px, progress)
    warnings = []
    if len(p.homographies) == 0 or len(p) < 200:
        raise ValueError(f"only {len(p.homographies)} pairs of captures overlap ({len(p)} samples): blind calibration "
                         "needs captures of the same surfaces from a turning camera (pan or tilt between them)")
    spread = turn_spread(p)
    if spread < MIN_TURN_SPREAD:
        raise ValueError(f"the captures turn one way only ({len(p.homographies)} overlapping pairs, direction spread "
                         f"{spread:.3f} < {MIN_TURN_SPREAD}): the field term across that direction cannot be "
                         "measured; turn the camera both ways between captures (pan and tilt)")
    if f_px is None:
        warnings.append(f"focal length {p.f_px:.0f} px fitted to the views' homographies (no --sensor-mm)")
    pupil_m = (pupil_mm if pupil_mm is not None else (identity.focal_length_mm or 0.0)) / 1000.0
    terms = poly_terms(degree, constant=False)
    lo = float(min(s.reported_d.min() for s in scenes))
    hi = float(max(s.reported_d.max() for s in scenes))
    coef, res = fit_field(p, degree, pupil_m, focus_degree=focus_degree, focus_range_d=(lo, hi))
    fp = FieldPoly(terms, coef, (lo, hi))
    # bootstrap over captures: Poisson weights per capture on both ends of a pair
    rng = np.random.default_rng(0)
    gx, gy = np.linspace(-1, 1, 13), np.linspace(-1, 1, 9)
    xx, yy = np.meshgrid(gx, gy)
    maps = []
    for _ in range(n_boot):
        wc = rng.poisson(1.0, len(scenes)).astype(np.float64)
        wb = p.weight * wc[p.ia] * wc[p.ib]
        if (wb > 0).sum() < 100:
            continue
        cb, _ = fit_field(p, degree, pupil_m, wb, focus_degree=focus_degree, focus_range_d=(lo, hi))
        maps.append(FieldPoly(terms, cb, (lo, hi))(xx, yy, [0.5 * (lo + hi)])[0])
    sd = np.std(np.array(maps), 0) if len(maps) > 1 else np.full(xx.shape, np.nan)
    mid = fp(xx, yy, [0.5 * (lo + hi)])[0]
    spread = spread_check(sd, mid - mid[len(gy) // 2, len(gx) // 2], scenes, len(maps))
    residuals = {"samples": int(len(p)), "pairs": len(p.homographies), "rms_d": float(np.sqrt(np.mean(res ** 2))),
                 "p95_d": float(np.quantile(np.abs(res), 0.95)), "f_px": float(p.f_px)}
    fit = {"method": "scenes", "captures": [s.name for s in scenes], "degree": degree, "focus_degree": focus_degree,
           "not_identified": NOT_IDENTIFIED, **(settings or {})}
    fe = FocusError("none", quantisation=None)
    cal = CameraCalibration(identity, size_px, fe, fp, None, sensor_mm, residuals,
                            {"x": gx.tolist(), "y": gy.tolist(),
                             "sd_d": np.round(sd, 6).tolist() if len(maps) > 1 else [],  # strict JSON: no NaN
                             "replicates": len(maps), "what": "bootstrap SD over captures of the field term",
                             **spread}, fit)
    if spread["warning"]:
        warnings.append(spread["warning"])
    warnings.append("blind calibration: " + NOT_IDENTIFIED)
    return BlindResult(cal, p, res, warnings)
