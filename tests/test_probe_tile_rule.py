"""benchmarks/probes/tile_rule.py and tile_size's judging copies (issue 33): the declared rule's arithmetic and the
refusals (the renders and fits themselves are the probes' own minutes, not tested here)."""

from __future__ import annotations

import json

import pytest

from benchmarks.probes import tile_rule as R
from benchmarks.probes import tile_size as TS


def _row(v, px, a, s):
    return {"variant": v, "tile_px": px, "part_a": {"rms_d": a}, "schedule": {"rms_d": s}}


def _rows(gains, sched_worse=0.0):
    out = []
    for k, g in enumerate(gains):
        v = TS.JUDGING[k]
        out += [_row(v, 27, 0.095, 0.18), _row(v, 24, 0.095 - g, 0.18 + sched_worse)]
    return out


def test_phone_conditions_need_every_copy_lower_and_the_mean_gain():
    six = len(TS.JUDGING)
    assert six == 6 and TS.JUDGING[0] == "copy_s2027_0"
    ok = R.phone_conditions(_rows([0.002] * six), TS.JUDGING)
    assert ok["condition_1"] and ok["condition_2"] and ok["mean_gain_d"] == pytest.approx(0.002)
    one_worse = R.phone_conditions(_rows([0.004] * (six - 1) + [-0.0001]), TS.JUDGING)
    assert not one_worse["condition_1"] and one_worse["mean_gain_d"] > R.MEAN_GAIN_D  # every copy, not the mean alone
    small = R.phone_conditions(_rows([0.0009] * six), TS.JUDGING)
    assert not small["condition_1"]  # all lower, but the mean under 0.001 D
    sched = R.phone_conditions(_rows([0.002] * six, sched_worse=0.0021), TS.JUDGING)
    assert sched["condition_1"] and not sched["condition_2"]
    missing = R.phone_conditions(_rows([0.002] * (six - 1)), TS.JUDGING)
    assert not missing["condition_1"] and missing["per_copy"][TS.JUDGING[-1]]["missing"] == [27, 24]


def _maps(v):
    return {"map": [{"lens": l, "variant": w, "inside": {"calibration": {"rms_d": v}}}
                    for l in R.OTHER_LENSES for w in ("nominal", "copy")]}


def test_other_lenses_allow_half_a_millidiopter_and_count_a_refusal_against():
    assert R.other_lenses(_maps(0.003), _maps(0.0034))["condition_3"]
    assert not R.other_lenses(_maps(0.003), _maps(0.0036))["condition_3"]
    refused = _maps(0.003)
    refused["map"][0] = {"lens": "rf50", "variant": "nominal", "refused": "too few tiles"}
    out = R.other_lenses(_maps(0.003), refused)
    assert not out["condition_3"] and out["per_map"]["rf50 nominal"] == {"missing_or_refused": True}


def test_main_writes_the_verdict_and_refuses_an_existing_out(tmp_path, capsys):
    ph, mb, ma = tmp_path / "p.json", tmp_path / "b.json", tmp_path / "a.json"
    ph.write_text(json.dumps({"rows": _rows([0.002] * 6)}))
    mb.write_text(json.dumps(_maps(0.003)))
    ma.write_text(json.dumps(_maps(0.0031)))
    out = tmp_path / "v.json"
    argv = ["--phone", str(ph), "--maps-before", str(mb), "--maps-after", str(ma), "--out", str(out)]
    assert R.main(argv) == 0
    assert json.loads(out.read_text())["adopted"] is True
    assert capsys.readouterr().out.strip().endswith("adopted")
    with pytest.raises(SystemExit):
        R.main(argv)
    assert "exists" in capsys.readouterr().err.strip().splitlines()[-1]


def test_tile_size_takes_the_judging_copies_and_refuses_others(tmp_path, capsys):
    for bad in ("copy_s2027_6", "copy_s2026_3"):
        with pytest.raises(SystemExit):
            TS.main(["--truth", "t.json", "--variants", f"nominal,{bad}", "--out", str(tmp_path / "o.json")])
        assert f"--variants: {bad} not of" in capsys.readouterr().err.strip().splitlines()[-1]
    assert not (tmp_path / "o.json").exists()


def test_a_judging_copy_is_drawn_from_its_own_seed():
    """copy_s2027_k is calibrate_copies' copy k of seed 2027 on the softened chart, named so its sweeps are cached
    apart from seed 2026's."""
    from benchmarks import bench_calibrate as B
    from benchmarks import calibrate_copies as C

    class Base:  # the rig's setup alone (rig_for reads and replaces it, nothing is rendered)
        def __init__(self, setup):
            self.setup = setup

        def with_setup(self, setup):
            return Base(setup)

    rig, v = TS.rig_for(Base(B.LENSES["cellphone_near"]), "copy_s2027_1")
    s = rig.setup
    assert v == "copy" and s.copy_name == "copy_s2027_1" and s.chart_soften_px == B.SOFT_SENSOR_PX
    from aat_deploy.lens.io import load_lens
    from aat_deploy.render.effects.lens_tolerance import elements

    n_el = len(elements(load_lens(B.ROOT / s.lens)))
    assert list(s.copy_effects) == C.draw_copy(B.LENSES["cellphone_near"], n_el, 2027, 1)["effects"]
    assert list(s.copy_effects) != C.draw_copy(B.LENSES["cellphone_near"], n_el, 2026, 1)["effects"]
