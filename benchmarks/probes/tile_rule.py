"""The verdict of the 24 px tiles' declaration (issue 33; docs/calibration.md, "24 px tiles, judged on unseen copies"),
computed from its committed result files by the rule declared before they were scored:

    python -m benchmarks.probes.tile_rule --phone results/tile_size_judge.json \
        --maps-before results/calibrate_map_tiles24_asis.json --maps-after results/calibrate_map_tiles27.json \
        --out results/tile_rule.json

Adopted (`sweep.TILES_PER_WIDTH` 24 -> 27) only if
  (1) part a inside (RMS, 7-18 cm, against the render truth) is lower with 24 px tiles than with 27 px on every
      judging copy (`tile_size.JUDGING`), and lower by at least MEAN_GAIN_D on their mean;
  (2) part a on the depth schedule (0.07-0.5 m) is on none of them worse with 24 px by more than SCHEDULE_SLACK_D;
  (3) the RF50, paper lens and EF50 maps (nominal and copy, part a inside) are none worse with tiles of 1/27 of the
      frame's width than with 1/24 by more than OTHER_LENS_SLACK_D.
A judging copy missing at either size, or a 50 mm row refused or missing, counts against adoption.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

OLD_PX, NEW_PX = 27, 24
MEAN_GAIN_D = 0.001
SCHEDULE_SLACK_D = 0.002
OTHER_LENS_SLACK_D = 0.0005
OTHER_LENSES = ("rf50", "paper50", "ef50")


def phone_conditions(rows: list[dict], judging: tuple) -> dict:
    """Conditions (1) and (2) from tile_size's rows: per judging copy part a inside and on the schedule, 27 -> 24 px."""
    by = {(r["variant"], r["tile_px"]): r for r in rows}
    per, ok1, ok2, gains = {}, True, True, []
    for v in judging:
        a, b = by.get((v, OLD_PX)), by.get((v, NEW_PX))
        if a is None or b is None:
            per[v] = {"missing": [px for px, r in ((OLD_PX, a), (NEW_PX, b)) if r is None]}
            ok1 = ok2 = False
            continue
        gain = a["part_a"]["rms_d"] - b["part_a"]["rms_d"]
        worse = b["schedule"]["rms_d"] - a["schedule"]["rms_d"]
        per[v] = {"part_a_d": [a["part_a"]["rms_d"], b["part_a"]["rms_d"]], "gain_d": gain,
                  "schedule_d": [a["schedule"]["rms_d"], b["schedule"]["rms_d"]], "schedule_worse_d": worse}
        gains.append(gain)
        ok1 &= gain > 0
        ok2 &= worse <= SCHEDULE_SLACK_D
    mean_gain = sum(gains) / len(gains) if gains else float("nan")
    ok1 &= bool(gains) and mean_gain >= MEAN_GAIN_D
    return {"per_copy": per, "mean_gain_d": mean_gain, "condition_1": bool(ok1), "condition_2": bool(ok2)}


def map_rows(doc: dict) -> dict:
    """{(lens, variant): part a inside RMS (D)} of a bench_calibrate --parts map result (None where refused)."""
    return {(r["lens"], r["variant"]): (r["inside"]["calibration"]["rms_d"] if "inside" in r else None)
            for r in doc.get("map", [])}


def other_lenses(before: dict, after: dict) -> dict:
    """Condition (3): each 50 mm lens's nominal and copy map, 1/24 -> 1/27."""
    b, a = map_rows(before), map_rows(after)
    per, ok = {}, True
    for lens in OTHER_LENSES:
        for v in ("nominal", "copy"):
            x, y = b.get((lens, v)), a.get((lens, v))
            if x is None or y is None:
                per[f"{lens} {v}"] = {"missing_or_refused": True}
                ok = False
                continue
            per[f"{lens} {v}"] = {"part_a_d": [x, y], "worse_d": y - x}
            ok &= (y - x) <= OTHER_LENS_SLACK_D
    return {"per_map": per, "condition_3": bool(ok)}


def main(argv=None) -> int:
    from aat_deploy.io.atomic import write_text_atomic
    from benchmarks.probes.tile_size import JUDGING

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--phone", required=True, help="tile_size's result on the judging copies at 27 and 24 px")
    ap.add_argument("--maps-before", required=True, help="bench_calibrate --parts map on the 50 mm lenses, 1/24")
    ap.add_argument("--maps-after", required=True, help="the same with tiles of 1/27 (patched_bench 'tiles 1/27')")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    if Path(a.out).exists():
        ap.error(f"{a.out}: exists (choose another --out)")
    docs = {}
    for k in ("phone", "maps_before", "maps_after"):
        try:
            docs[k] = json.loads(Path(getattr(a, k)).read_text())
        except (OSError, ValueError) as e:
            ap.error(f"--{k.replace('_', '-')} {getattr(a, k)}: {e}")
    ph = phone_conditions(docs["phone"]["rows"], JUDGING)
    ot = other_lenses(docs["maps_before"], docs["maps_after"])
    adopted = ph["condition_1"] and ph["condition_2"] and ot["condition_3"]
    out = {"what": __doc__.split("\n")[0], "inputs": {k: getattr(a, k) for k in ("phone", "maps_before", "maps_after")},
           "rule": {"old_px": OLD_PX, "new_px": NEW_PX, "mean_gain_d": MEAN_GAIN_D,
                    "schedule_slack_d": SCHEDULE_SLACK_D, "other_lens_slack_d": OTHER_LENS_SLACK_D},
           "phone": ph, "other_lenses": ot, "adopted": bool(adopted)}
    write_text_atomic(a.out, json.dumps(out, indent=1, default=float))
    for v, p in ph["per_copy"].items():
        print(f"{v}: " + (f"missing {p['missing']}" if "missing" in p else
                          f"part a {p['part_a_d'][0]:.4f} -> {p['part_a_d'][1]:.4f} D, schedule "
                          f"{p['schedule_d'][0]:.4f} -> {p['schedule_d'][1]:.4f} D"))
    for k, p in ot["per_map"].items():
        print(f"{k}: " + ("missing or refused" if "part_a_d" not in p else
                          f"{p['part_a_d'][0]:.5f} -> {p['part_a_d'][1]:.5f} D"))
    print(f"mean gain {ph['mean_gain_d']:.4f} D; conditions 1 {ph['condition_1']}, 2 {ph['condition_2']}, "
          f"3 {ot['condition_3']}: {'adopted' if adopted else 'not adopted'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
