"""benchmarks.probes.copies_compare: two runs of the same random copies paired scene by scene."""

from __future__ import annotations

import json

import pytest

from benchmarks.probes import copies_compare as C


def _run(cal_scale: dict[int, float], fixed_shift: float = 0.0, seed: int = 2026) -> dict:
    copies = []
    for k, s in cal_scale.items():
        per = {}
        for m, base in (("thin lens", 0.06), ("prescription map", 0.05), ("calibration", 0.04), ("oracle", 0.04)):
            f = s if m == "calibration" else 1.0
            add = fixed_shift if m == "prescription map" else 0.0
            per[m] = [{"scene": f"s{i}", "mae": base * (1 + 0.1 * i) * f + add,
                       "mae_outer": 2 * base * (1 + 0.05 * i) * f + add, "mae_d": base * 10 * f + add}
                      for i in range(6)]
        copies.append({"index": k, "map": {"inside": {"calibration": {"rms_d": 0.1}}},
                       "depth": {"per_scene": per}})
    return {"copies": {"phone": {"seed": seed, "n": 6, "distribution": {"x": 1}, "copies": copies}}}


def test_a_run_against_itself_is_one_and_a_uniform_scale_is_found():
    r = C.compare(_run({0: 1.0, 1: 1.0}), _run({0: 1.0, 1: 1.0}), "phone")
    assert all(r["pooled"][f"a/b {z}"][0] == pytest.approx(1.0) for z in C.ZONES)
    r = C.compare(_run({0: 0.9, 1: 0.9}), _run({0: 1.0, 1: 1.0}), "phone")
    for z in C.ZONES:
        assert r["pooled"][f"a/b {z}"][0] == pytest.approx(0.9)
        assert [c["copy"] for c in r["copies"]] == [0, 1]
        assert r["copies"][0][f"a/b {z}"][0] == pytest.approx(0.9)
    r = C.compare(_run({0: 0.9, 1: 1.0}), _run({0: 1.0, 1: 1.0}), "phone")  # only copy 0 changed
    assert r["copies"][1]["a/b mae"][0] == pytest.approx(1.0)
    assert 0.9 < r["pooled"]["a/b mae"][0] < 1.0
    assert "| pooled, 2 copies |" in C.table(r)


def test_only_the_copies_both_hold_are_paired():
    r = C.compare(_run({0: 0.9, 1: 0.8, 2: 0.7}), _run({1: 1.0}), "phone")
    assert [c["copy"] for c in r["copies"]] == [1]
    assert r["pooled"]["a/b mae"][0] == pytest.approx(0.8)


def test_other_copies_or_other_stacks_are_refused():
    with pytest.raises(SystemExit, match="seed"):
        C.compare(_run({0: 1.0}), _run({0: 1.0}, seed=1), "phone")
    with pytest.raises(SystemExit, match="not the same held-out stacks"):
        C.compare(_run({0: 1.0}), _run({0: 1.0}, fixed_shift=1e-6), "phone")
    with pytest.raises(SystemExit, match="not in both"):
        C.compare(_run({0: 1.0}), _run({0: 1.0}), "rf50")
    with pytest.raises(SystemExit, match="no copy scored in both"):
        C.compare(_run({0: 1.0}), _run({1: 1.0}), "phone")


def test_main_writes_its_out_and_refuses_an_existing_one(tmp_path, capsys):
    a, b, out = tmp_path / "a.json", tmp_path / "b.json", tmp_path / "out.json"
    a.write_text(json.dumps(_run({0: 0.95})))
    b.write_text(json.dumps(_run({0: 1.0})))
    assert C.main([str(a), str(b), "--lens", "phone", "--out", str(out)]) == 0
    assert json.loads(out.read_text())["pooled"]["a/b mae"][0] == pytest.approx(0.95)
    assert C.main([str(a), str(b), "--lens", "phone", "--out", str(out)]) == 2
    assert "exists" in capsys.readouterr().err
    assert C.main([str(a), str(tmp_path / "none.json"), "--lens", "phone", "--out", str(tmp_path / "o2.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "none.json: no such results file" in err[0] and not (tmp_path / "o2.json").exists()


def test_the_hand_chosen_copys_runs_are_paired_scene_by_scene(tmp_path, capsys):
    def single(scale, shift=0.0):
        per = _run({0: scale}, fixed_shift=shift)["copies"]["phone"]["copies"][0]["depth"]["per_scene"]
        return {"map": [], "depth": {"phone": {"per_scene": per}}}

    r = C.compare_copy(single(0.9), single(1.0), "phone")
    assert [c["copy"] for c in r["copies"]] == ["hand-chosen"] and "pooled" not in r
    assert all(r["copies"][0][f"a/b {z}"][0] == pytest.approx(0.9) for z in C.ZONES)
    with pytest.raises(SystemExit, match="not the same held-out stacks"):
        C.compare_copy(single(1.0), single(1.0, shift=1e-6), "phone")
    with pytest.raises(SystemExit, match="not in both"):
        C.compare_copy(single(1.0), single(1.0), "rf50")
    a, b, out = tmp_path / "a.json", tmp_path / "b.json", tmp_path / "out.json"
    a.write_text(json.dumps(single(0.95)))
    b.write_text(json.dumps(single(1.0)))
    assert C.main([str(a), str(b), "--lens", "phone", "--out", str(out)]) == 0
    assert "| hand-chosen | nan / nan | 0.950" in capsys.readouterr().out
    assert json.loads(out.read_text())["copies"][0]["a/b mae"][0] == pytest.approx(0.95)
