"""benchmarks.probes.anycam_choose_sizes: the declared rule (mean over frame counts of MAE / classical MAE) on
hand-made results whose answer is computed by hand."""

import json

import pytest

from benchmarks.probes import anycam_choose_sizes as cs


def result(size, classical, rows, first=12):
    return {"lens": "rf50", "split": "validation", "first": first, "n": len(classical), "stack_size": size,
            "classical_lens_map": {"mae_m": classical},
            "rows": [{"checkpoint": ck, "step": 0, "mae_m": v} for ck, v in rows.items()]}


def write(tmp_path, name, r):
    p = tmp_path / name
    p.write_text(json.dumps(r))
    return p


def test_the_rule_weighs_each_frame_count_alike(tmp_path, capsys):
    # 3 frames: classical 4 m; 8 frames: classical 0.4 m. A: 2/4 = 0.5 and 0.4/0.4 = 1 -> 0.75;
    # B: 4/4 = 1 and 0.2/0.4 = 0.5 -> 0.75 (a tie: A, given first); C: 3/4 and 0.3/0.4 -> 0.75 ... make C lose
    s3 = write(tmp_path, "s3.json", result(3, [3.0, 5.0], {"A": [2.0, 2.0], "B": [4.0, 4.0], "C": [3.0, 3.2]}))
    s8 = write(tmp_path, "s8.json", result(8, [0.4, 0.4], {"A": [0.4, 0.4], "B": [0.2, 0.2], "C": [0.3, 0.3]}))
    out = tmp_path / "choice.json"
    assert cs.main(["--select", str(s3), str(s8), "--out", str(out)]) == 0
    got = json.loads(out.read_text())
    assert got["chosen"] == "A"  # A and B tie at 0.75; C scores (3.1/4 + 0.75) / 2 = 0.7625
    assert got["candidates"]["B"]["score"] == pytest.approx(0.75)
    assert got["candidates"]["C"]["score"] == pytest.approx((3.1 / 4 + 0.75) / 2)
    assert got["candidates"]["A"]["ratios"] == {"3": pytest.approx(0.5), "8": pytest.approx(1.0)}
    assert "A (chosen)" in capsys.readouterr().out


def test_parts_pool_and_candidates_missing_a_count_are_left_out(tmp_path):
    s3a = write(tmp_path, "a.json", result(3, [4.0], {"A": [2.0]}))
    s3b = write(tmp_path, "b.json", result(3, [4.0], {"B": [1.0]}))
    s8 = write(tmp_path, "c.json", result(8, [1.0], {"A": [0.5], "B": [2.0], "D": [0.1]}))
    out = tmp_path / "o.json"
    cs.main(["--select", str(s3a), str(s3b), str(s8), "--out", str(out)])
    got = json.loads(out.read_text())
    assert got["chosen"] == "A" and got["left_out"] == ["D"]  # A 0.5, B 1.125; D has no 3-frame score


def test_refusals_name_the_problem(tmp_path, capsys):
    s3 = write(tmp_path, "s3.json", result(3, [4.0], {"A": [2.0]}))
    other = write(tmp_path, "s8.json", result(8, [1.0], {"A": [0.5]}, first=0))
    with pytest.raises(SystemExit, match="different stacks"):
        cs.main(["--select", str(s3), str(other)])
    with pytest.raises(SystemExit):
        cs.main(["--select", str(s3)])
    assert "at least two frame counts" in capsys.readouterr().err
    old = result(8, [1.0], {"A": [0.5]})
    del old["stack_size"]
    with pytest.raises(SystemExit, match="no stack_size"):
        cs.main(["--select", str(s3), str(write(tmp_path, "old.json", old))])
    twice = write(tmp_path, "twice.json", result(3, [4.0], {"A": [3.0]}))
    with pytest.raises(SystemExit, match="A: scored twice with 3 frames, differently"):
        cs.main(["--select", str(s3), str(twice), str(write(tmp_path, "s8b.json", result(8, [1.0], {"A": [0.5]})))])
    out = tmp_path / "taken.json"
    out.write_text("mine")
    with pytest.raises(SystemExit):
        cs.main(["--select", str(s3), str(s3), "--out", str(out)])
    assert "exists" in capsys.readouterr().err and out.read_text() == "mine"


def test_route_threshold_is_the_last_count_of_an_unbroken_run_of_small_wins(tmp_path, capsys):
    # classical 1 m everywhere; S wins at 3 and 5, loses at 8, would win again at 12: T = 5, not 12
    files = [write(tmp_path, f"s{n}.json", result(n, [1.0], {"S": [s], "L": [ll]}))
             for n, s, ll in ((3, 0.4, 2.0), (5, 0.6, 0.9), (8, 0.75, 0.70), (12, 0.5, 0.6))]
    out = tmp_path / "route.json"
    assert cs.main(["--select", *map(str, files), "--route", "S", "L", "--out", str(out)]) == 0
    got = json.loads(out.read_text())
    assert got["max_small_frames"] == 5
    assert got["ratios"]["8"] == {"S": pytest.approx(0.75), "L": pytest.approx(0.70)}
    assert "threshold T = 5" in capsys.readouterr().out
    # a tie goes to LARGE; LARGE better at the fewest frames: nothing to route
    tie = [write(tmp_path, f"t{n}.json", result(n, [1.0], {"S": [v], "L": [v]})) for n, v in ((3, 1.0), (5, 0.5))]
    sizes = cs.by_size([json.loads(p.read_text()) for p in tie])
    assert cs.route_threshold(sizes, "S", "L") is None
    with pytest.raises(SystemExit, match="X: not scored with 3 frames"):
        cs.route_threshold(sizes, "X", "L")
