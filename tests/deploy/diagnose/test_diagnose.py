"""aat-diagnose: its statistics against hand-computed cases, and end to end on virtual captures whose
withheld effect is known."""

import dataclasses
import json

import numpy as np
import pytest
import torch
from conftest import ROOT

from aat_deploy.diagnose import bins as B
from aat_deploy.diagnose.bootstrap import binned_bootstrap, capture_bootstrap, ratio_bootstrap
from aat_deploy.diagnose.compare import focus_curves, region_shifts
from tests.deploy_fixtures import build_tiny_dff

RF50 = "lenses/canon_rf50mm_f1.8.json"


def test_binned_bootstrap_means_and_intervals():
    rng = np.random.default_rng(0)
    vals = [rng.normal(0.3, 0.05, (64, 64)), rng.normal(0.3, 0.05, (64, 64))]
    idx = [np.zeros((64, 64), int), np.zeros((64, 64), int)]
    for v, i in zip(vals, idx):
        i[:, 32:] = 1
        v[:, 32:] -= 0.3  # bin 1: mean 0
        v[0, 0] = np.nan  # unknown pixels are skipped
    st = binned_bootstrap(vals, idx, 3, n_boot=300)
    # 4,094 draws of sd 0.05: the mean's standard error is 8e-4 (0.3 % of it)
    assert st.mean[0] == pytest.approx(0.3, rel=0.03) and st.ci_low[0] > 0.25 and st.ci_high[0] < 0.35
    assert st.ci_low[1] < 0 < st.ci_high[1]
    assert st.pixels.tolist() == [2 * 64 * 32 - 2, 2 * 64 * 32, 0] and np.isnan(st.mean[2])


def test_ratio_and_capture_bootstrap():
    num = [np.full((32, 32), 1.0), np.full((32, 32), 3.0)]
    den = [np.full((32, 32), 4.0), np.full((32, 32), 4.0)]
    est, lo, hi = ratio_bootstrap(num, den, 200)
    assert est == pytest.approx(0.5) and lo <= 0.5 <= hi
    m, lo, hi = capture_bootstrap(np.array([1.0, 3.0]), np.array([1.0, 1.0]), 200)
    assert m == 2.0 and 1.0 <= lo <= hi <= 3.0


def test_covariates_by_hand():
    r = B.field_radius(4, 6)
    assert r[0, 0] == pytest.approx(np.hypot(2.5, 1.5) / np.hypot(3, 2)) and r.min() > 0
    gt = np.full((4, 6), 2.2, np.float32)
    gt[0, 0] = np.nan
    focus = np.array([1.0, 2.5, 5.0])  # 1.0, 0.4, 0.2 diopters; a 2.2 m point is 0.4545 D: 0.055 D from frame 1
    bs = {b.name: b for b in B.make_binnings(gt, focus, np.ones((3, 4, 6), np.float32),
                                             np.array([0, 1.5, 3.0, np.inf]), np.array([-np.inf, np.inf]))}
    assert (bs["frame"].index[1:] == 1).all() and bs["frame"].index[0, 0] == -1
    assert bs["defocus"].labels[bs["defocus"].index[1, 1]] == "0.05-0.10"
    assert bs["depth"].labels[bs["depth"].index[1, 1]] == "1.50-3.00"


def test_focus_curves_and_shifts():
    rng = np.random.default_rng(1)
    sharp = rng.random((1, 96, 128)).astype(np.float32)
    import cv2
    blurred = cv2.GaussianBlur(sharp[0], (0, 0), 2.0)[None]
    stack = np.stack([np.repeat(blurred, 3, 0), np.repeat(sharp, 3, 0)])  # frame 1 sharp
    c = focus_curves(stack, (2, 2))
    assert c.shape == (4, 2, 3) and (c[:, 1] > c[:, 0] + 1).all()
    smooth = np.repeat(cv2.GaussianBlur(sharp[0], (0, 0), 1.0)[None], 3, 0)[None]
    moved = np.roll(smooth, 2, axis=3)  # 2 px to the right
    sh = region_shifts(smooth, moved, (2, 2))
    # phase correlation's sub-pixel peak is biased low on smooth content (about 20 % here): a distance, not a
    # measurement; the direction and the order of magnitude are what the diagnosis needs
    assert (sh[..., 0] > 1.4).all() and (sh[..., 0] < 2.2).all() and np.allclose(sh[..., 1], 0.0, atol=0.2)
    assert np.allclose(region_shifts(smooth, smooth, (2, 2)), 0.0, atol=1e-3)


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """A classical-DfF model 'trained' for the RF50 on a 192x128 sensor with the thin-lens simulator, and capture
    sets rendered with that simulator, with and without a withheld focus-metadata bias."""
    from aat_deploy.capture.virtual import write_capture
    from aat_deploy.lens.io import load_lens
    from aat_deploy.render import effects as fx
    from training.data.scenes import SceneConfig, procedural_scene
    from training.render.layered import LayeredConfig
    from training.render.simulator import Simulator
    from training.render.sources import thin_lens_source

    tmp = tmp_path_factory.mktemp("diag")
    lens = load_lens(RF50)
    lens = dataclasses.replace(lens, sensor=dataclasses.replace(lens.sensor, width_px=192, height_px=128))
    model = build_tiny_dff(tmp / "tiny.onnx", {"aat.lens_name": lens.name, "aat.sensor_mm": [36.0, 24.0],
                                               "aat.sensor_px": [192, 128], "aat.pixel_um": 187.5,
                                               "aat.focus_range_m": [0.5, 10.0]}, sharpness=20.0)
    focus = 1.0 / np.linspace(1.6, 0.25, 6)
    sets = {}
    for name, extra in (("bias", [fx.make("focus_metadata", bias_d=0.25)]), ("none", [])):
        sim = Simulator(lens, None, extra, LayeredConfig(cell_px=32), thin_lens_source(lens))
        for s in range(3):
            rgb, depth = procedural_scene(SceneConfig(height=128, width=192, near_m=0.8, far_m=3.0), np.random.default_rng(s))
            rgb = np.ascontiguousarray(rgb.transpose(2, 0, 1))
            st = sim.render_stack(torch.from_numpy(rgb), torch.from_numpy(depth), focus, rng=np.random.default_rng(s))
            write_capture(tmp / name / f"scene{s}", st.frames.numpy(), st.focus_reported_m, lens, depth, rgb, {})
        sets[name] = tmp / name
    return tmp, model, sets


def test_withheld_focus_bias_is_named(setup):
    from aat_deploy.cli.diagnose import main

    tmp, model, sets = setup
    out = tmp / "out_bias"
    assert main([str(sets["bias"]), "--model", str(model), "--lens", RF50, "--out", str(out),
                 "--effects", "focus_metadata,noise", "-q"]) == 0
    d = json.loads((out / "diagnosis.json").read_text())
    assert d["gap_significant"] is True and d["where"]
    assert d["verdict"] in ("explained", "partly_explained") and d["causes"][0] == "focus_metadata"
    u = d["unexplained_share"]
    assert u["ci_low"] <= u["share"] <= u["ci_high"] and 0 <= u["shown"] <= 1
    top = d["ranked_effects"][0]
    assert top["effect"] == "focus_metadata" and _correction_d(d) > 0.15  # the sign and size of the bias (0.25 D)
    for k in ("share_of_gap", "ci_low", "ci_high"):
        assert isinstance(top[k], float)
    assert top["ci_low"] <= top["share_of_gap"] <= top["ci_high"] and top["share_of_gap"] > 0.3
    assert d["shrink"]["gap_predicted_m"] < d["shrink"]["gap_before_m"]
    assert "aat-train" in d["shrink"]["retrain_command"] and "focus_metadata" in d["shrink"]["retrain_command"]
    for f in ("report.md", "gap_where.png", "gap_by.png", "effects.png", "diagnosis.rrd"):
        assert (out / f).stat().st_size > 0
    assert "focus_metadata" in (out / "report.md").read_text()
    # an existing report is not overwritten without --force
    assert main([str(sets["bias"]), "--model", str(model), "--lens", RF50, "--out", str(out), "-q"]) == 2


def _correction_d(d: dict) -> float:
    """Mean reported minus corrected focus (diopters) over every capture frame: the fitted bias, whatever family
    (offset, or a curve when the DNG development bends the estimates) the fit chose."""
    c = d["focus"]["corrected_focus"]
    return float(np.mean([1 / np.array(x["reported_m"]) - 1 / np.array(x["corrected_m"]) for x in c]))


def test_no_withheld_effect_is_not_blamed(setup):
    from aat_deploy.cli.diagnose import main

    tmp, model, sets = setup
    out = tmp / "out_none"
    assert main([str(sets["none"]), "--model", str(model), "--lens", RF50, "--out", str(out),
                 "--effects", "focus_metadata,noise", "-q"]) == 0
    d = json.loads((out / "diagnosis.json").read_text())
    assert d["gap_significant"] is False and d["ranked_effects"] == [] and d["where"] == []
    assert d["verdict"] == "no_gap" and d["unexplained_share"] is None and d["causes"] == []
    assert d["image_effects"] == []  # nor does it claim to see one in the images
    assert "Nothing to blame" in (out / "report.md").read_text()


def test_bad_inputs_get_one_line_errors(setup, tmp_path, capsys):
    from aat_deploy.cli.diagnose import main

    _, model, _ = setup
    (tmp_path / "empty").mkdir()
    assert main([str(tmp_path / "empty"), "--model", str(model), "--lens", RF50, "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err.strip()
    assert "no capture folder with ground truth" in err and "\n" not in err
    _, _, sets = setup
    assert main([str(sets["bias"]), "--model", str(model), "--lens", RF50, "--out", str(tmp_path / "o"),
                 "--effects", "noise,lens_flare"]) == 1
    err = capsys.readouterr().err.strip()
    assert "unknown lens_flare" in err and "\n" not in err and not (tmp_path / "o").exists()
    with pytest.raises(SystemExit) as e:
        main(["--list-effects"])
    assert e.value.code == 0
    listed = capsys.readouterr().out
    for name in ("aberrations", "focus_metadata", "sensor_tilt", "noise", "vignetting"):
        assert name in listed


def test_diagnosis_runs_without_torch(setup, tmp_path):
    """The whole `aat-diagnose` in an interpreter where torch cannot be imported: same answer as with torch, and
    an effect only torch can render (chromatic) is listed as skipped instead of guessed."""
    from deploy_fixtures import run_without_torch as _run

    tmp, model, sets = setup
    out = tmp_path / "out"
    r = _run(f"""
        import json, sys
        from aat_deploy.cli.diagnose import main
        code = main([{str(sets["bias"])!r}, "--model", {str(model)!r}, "--lens", {str(ROOT / RF50)!r},
                     "--out", {str(out)!r}, "--effects", "focus_metadata,noise,chromatic", "-q"])
        print(json.dumps({{"code": code, "torch": any(k == "torch" or k.startswith("torch.") for k in sys.modules)}}))
    """, tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    assert json.loads(r.stdout.strip().splitlines()[-1]) == {"code": 0, "torch": False}
    d = json.loads((out / "diagnosis.json").read_text())
    top = d["ranked_effects"][0]
    assert top["effect"] == "focus_metadata" and _correction_d(d) > 0.15 and top["share_of_gap"] > 0.3
    assert [e["effect"] for e in d["effects_skipped"]] == ["chromatic"] and "torch" in d["effects_skipped"][0]["reason"]
    assert "chromatic" in (out / "report.md").read_text()


def test_naming_rule_by_hand():
    from aat_deploy.diagnose.search import is_named

    # significant in images and errors together
    assert is_named({"closeness": 0.3, "closeness_ci": [0.1, 0.5]}, 0.05)
    # the two-effect set's tilt in round 2: one capture's error pattern moved away (-0.03), every capture's
    # images came closer (0.11-0.14): named on the images, with a mean gain of 0.14
    tilt = {"closeness": 0.141, "closeness_ci": [-0.027, 0.271], "image_closeness": 0.125,
            "image_closeness_ci": [0.111, 0.141]}
    assert is_named(tilt, 0.05)
    # images alone are not enough when the mean gain is small, nor a mean gain without the images
    assert not is_named(dict(tilt, closeness=0.04), 0.05)
    assert not is_named(dict(tilt, image_closeness_ci=[0.01, 0.2]), 0.05)
    assert not is_named({"closeness": 0.2, "closeness_ci": [0.0, 0.4]}, 0.05)


def test_brightness_distance_sees_fall_off_not_exposure():
    """A corner fall-off (vignetting) is a brightness distance; a global exposure change is none; the distance
    is the mean |log ratio - median| over the map's regions, checked on a hand-made two-level case."""
    from aat_deploy.diagnose.bins import MAP_GRID
    from aat_deploy.diagnose.compare import brightness_distance, region_index

    rng = np.random.default_rng(0)
    stack = rng.uniform(0.2, 0.8, (3, 3, 64, 96)).astype(np.float32)
    assert brightness_distance(stack, 2.0 * stack) == pytest.approx(0.0, abs=1e-6)
    reg = region_index(64, 96)
    n = MAP_GRID[0] * MAP_GRID[1]
    dark = np.isin(reg, np.arange(n)[: n // 4])  # a quarter of the regions at half the light
    flat = np.full_like(stack, 0.5)
    # log ratio 0 in 3/4 of the regions, log 2 in 1/4: median 0, mean |.| = log(2) / 4
    assert brightness_distance(flat, flat * np.where(dark, 0.5, 1.0)) == pytest.approx(np.log(2) / 4, rel=1e-5)
    y, x = np.mgrid[0:64, 0:96]
    falloff = (1 - 0.5 * (((x - 47.5) / 48) ** 2 + ((y - 31.5) / 32) ** 2) / 2).astype(np.float32)
    assert brightness_distance(stack * falloff, stack) > 0.05
    assert brightness_distance(stack * falloff, stack * falloff) == pytest.approx(0.0, abs=1e-6)


def test_brightness_fallback_rule_by_hand():
    """named_by_brightness: lit significantly more like the captures AND a significant share of the gap."""
    from aat_deploy.diagnose.search import named_by_brightness

    # the shipped sample's round 2: vignetting after noise (images -0.03, lighting 0.64, share 0.63)
    vign = {"brightness_closeness": 0.644, "brightness_closeness_ci": [0.644, 0.644], "image_closeness": -0.03,
            "image_closeness_ci": [-0.03, -0.03], "share_of_gap": 0.63, "ci_low": 0.56, "ci_high": 0.71}
    assert named_by_brightness(vign, 0.05)
    # its round 3: focus breathing, which the capture lacks, moves the images far away (-1.24) although the
    # shifted edges change the regions' brightness (0.28) and the share is large
    breathing = dict(vign, brightness_closeness=0.282, brightness_closeness_ci=[0.282, 0.282],
                     image_closeness=-1.242, image_closeness_ci=[-1.242, -1.242], share_of_gap=0.99, ci_low=0.86)
    assert not named_by_brightness(breathing, 0.05)
    assert not named_by_brightness(dict(vign, ci_low=-0.1), 0.05)  # no significant share of the gap
    assert not named_by_brightness(dict(vign, brightness_closeness_ci=[0.01, 0.6]), 0.05)
    assert not named_by_brightness(dict(vign, ci_low=None), 0.05)  # no gap: the image-only search never uses it


def test_hidden_cause_is_unexplained_not_blamed(setup):
    """The focus bias hidden from the search (only noise and breathing may be tried): the gap is real, nothing
    explains it, and the report says so instead of naming a wrong effect."""
    from aat_deploy.cli.diagnose import main

    tmp, model, sets = setup
    out = tmp / "out_hidden"
    assert main([str(sets["bias"]), "--model", str(model), "--lens", RF50, "--out", str(out),
                 "--effects", "noise,focus_breathing", "-q"]) == 0
    d = json.loads((out / "diagnosis.json").read_text())
    assert d["gap_significant"] is True
    assert d["verdict"] == "unexplained" and d["causes"] == []
    u = d["unexplained_share"]
    assert u["shown"] == pytest.approx(1.0, abs=0.05) and u["ci_low"] > 0.5
    report = (out / "report.md").read_text()
    assert "Verdict: unexplained" in report and "no registered effect explains it" in report


def test_shares_shown_only_when_meaningful():
    """share_view on the cases the issue met: a share of 8.75 from an effect whose images moved away is withheld
    with the reason; shares past 0..1 are clipped with a note; a plain one is shown as is."""
    from aat_deploy.diagnose.verdict import share_view

    away = {"share_of_gap": 8.75, "ci_low": 2.0, "ci_high": 15.0, "closeness": -1.18, "image_closeness": -1.18}
    shown, note = share_view(away)
    assert shown is None and "moved away" in note and "8.75" in note
    over = {"share_of_gap": 1.26, "ci_low": 1.1, "ci_high": 1.4, "closeness": 0.6, "image_closeness": 0.5}
    assert share_view(over) == (1.0, share_view(over)[1]) and "clipped to 1" in share_view(over)[1]
    under = dict(over, share_of_gap=-0.2, ci_low=-0.3, ci_high=-0.1)
    assert share_view(under)[0] == 0.0 and "widens" in share_view(under)[1]
    plain = dict(over, share_of_gap=0.63, ci_low=0.56, ci_high=0.71)
    assert share_view(plain) == (0.63, None)
    assert "includes 0" in share_view(dict(plain, ci_low=-0.05))[1]
    assert share_view({"share_of_gap": None, "closeness": 0.3})[0] is None


def test_verdict_by_hand():
    """no_gap / unexplained / partly_explained / explained from hand-made ranked effects."""
    from aat_deploy.diagnose.gap import DiagnoseConfig
    from aat_deploy.diagnose.verdict import explains_gap, verdict

    cfg = DiagnoseConfig()
    # the shipped sample: noise named first (share -0.20), then vignetting on its lighting
    noise = {"share_of_gap": -0.2, "ci_low": -0.3, "ci_high": -0.1, "image_closeness": 0.34}
    vign = {"share_of_gap": 0.63, "ci_low": 0.56, "ci_high": 0.71, "image_closeness": -0.03,
            "brightness_closeness": 0.64}
    away = {"share_of_gap": 0.9, "ci_low": 0.5, "ci_high": 1.2, "image_closeness": -0.4, "brightness_closeness": 0.1}
    # a focus bias hidden from the search: weak noise stands in for it (the test set's own numbers)
    stand_in = {"share_of_gap": 0.48, "ci_low": 0.16, "ci_high": 1.12, "image_closeness": 0.107,
                "brightness_closeness": 0.0}
    bias = {"share_of_gap": 0.95, "ci_low": 0.8, "ci_high": 1.1, "image_closeness": 0.7}
    lim = (cfg.min_share, cfg.min_image_explained)
    assert not explains_gap(noise, *lim) and explains_gap(vign, *lim) and explains_gap(bias, *lim)
    assert not explains_gap(away, *lim)  # a twin unlike the captures explains nothing
    assert not explains_gap(stand_in, *lim)
    assert not explains_gap(dict(bias, share_of_gap=0.05, ci_low=0.01), *lim)  # too small a part
    assert verdict(False, [vign], None, cfg) == "no_gap"
    assert verdict(True, [], 1.0, cfg) == "unexplained"
    assert verdict(True, [noise], 1.2, cfg) == "unexplained"
    assert verdict(True, [stand_in], 0.52, cfg) == "unexplained"
    assert verdict(True, [noise, vign], 0.57, cfg) == "partly_explained"
    assert verdict(True, [bias], 0.05, cfg) == "explained"


def _focus_entry(family: str, support: dict, reported_m, ci_m, **numbers) -> dict:
    """A named focus_metadata entry as the search makes it, with its fit's report (`fitters.fit_focus_metadata`)."""
    fit = {"focus_fit": {"family": family, "support": support},
           "corrected_focus": [{"capture": "c", "reported_m": list(reported_m), "ci_m": [list(x) for x in ci_m]}]}
    return {"effect": "focus_metadata", "fit": fit, **numbers}


def test_focus_metadata_is_blamed_on_its_measured_focus_not_on_its_images():
    """A focus error changes the model's depth a lot and the images little: benchmark set scale 0.9 on the
    shipped sample (bench_diagnose_focus) closed 1.12 of the gap while its images came only 0.10 closer. The fit
    measured every frame focused elsewhere than reported (scale chosen in every replicate, the reported focus
    outside the corrected intervals): it explains the gap. The same numbers without that measurement do not: an
    untouched copy (family none, or an error in too few replicates, or the reported focus inside the intervals),
    or any other effect (the stand-in rule holds)."""
    from aat_deploy.diagnose.gap import DiagnoseConfig
    from aat_deploy.diagnose.verdict import explains_gap, focus_measured, verdict

    cfg = DiagnoseConfig()
    lim = (cfg.min_share, cfg.min_image_explained, cfg.min_focus_support)
    numbers = {"share_of_gap": 1.119, "ci_low": 1.075, "ci_high": 1.165, "image_closeness": 0.101,
               "brightness_closeness": 0.001}
    rep = [0.54, 1.8, 5.4]  # reported 0.9 x the true 0.6, 2, 6 m
    ci = [(0.597, 0.603), (1.98, 2.02), (5.8, 6.2)]
    found = _focus_entry("scale", {"scale": 1.0}, rep, ci, **numbers)
    assert focus_measured(found) and explains_gap(found, *lim)
    assert verdict(True, [found], -0.119, cfg) == "explained"
    # scene 2027's untouched copy: none chosen, scale in 13 % of the replicates
    untouched = _focus_entry("none", {"none": 0.87, "scale": 0.13}, rep, ci, **numbers)
    assert not focus_measured(untouched) and not explains_gap(untouched, *lim)
    assert verdict(True, [untouched], 1.0, cfg) == "unexplained"
    weak = _focus_entry("scale", {"none": 0.1, "scale": 0.9}, rep, ci, **numbers)
    assert not explains_gap(weak, *lim)
    inside = _focus_entry("scale", {"scale": 1.0}, rep, [(0.5, 0.61), (1.7, 2.1), (5.0, 6.5)], **numbers)
    assert not explains_gap(inside, *lim)
    assert not explains_gap(dict(found, effect="noise"), *lim)  # a stand-in is still judged on its images
    assert not explains_gap(dict(found, share_of_gap=0.05, ci_low=0.01), *lim)  # too small a part of the gap
    assert not explains_gap(dict(found, image_closeness=-0.3), *lim)  # its images moved away


def test_focus_metadata_is_named_on_its_measured_focus():
    """Issue 32: focus metadata named by its fit's measurement (`search.named_by_focus`), not by closeness. Scene
    2027's scale 0.95 (results/diagnose_focus_all36.jsonl): the fit chose scale in every replicate, correcting the
    focus closed 2.24 of the gap (interval from 2.02), its images came 0.06 closer and its closeness was -0.03, so
    noise (closeness 0.13) was named and focus metadata never. Now it is named first and explains the gap; with
    images moving 0.02 away (the benchmark's noise) too. Not: an untouched copy (family none), too few replicates,
    a share whose interval reaches 0, images that moved far away, or any other effect with the same numbers."""
    from aat_deploy.diagnose.gap import DiagnoseConfig
    from aat_deploy.diagnose.search import Diagnosis, named_by_focus
    from aat_deploy.diagnose.verdict import explains_gap, share_view

    cfg = DiagnoseConfig()
    lim = (cfg.min_share, cfg.min_image_explained, cfg.min_focus_support)
    numbers = {"closeness": -0.034, "closeness_ci": [-0.034, -0.034], "image_closeness": 0.061,
               "image_closeness_ci": [0.061, 0.061], "brightness_closeness": 0.0, "share_of_gap": 2.24,
               "ci_low": 2.02, "ci_high": 2.5}
    rep = [0.63, 2.1, 6.3]  # reported 1 / 0.95 x the true 0.6, 2, 6 m
    ci = [(0.597, 0.603), (1.98, 2.02), (5.8, 6.2)]
    found = _focus_entry("scale", {"scale": 0.71, "monotone": 0.29}, rep, ci, **numbers)
    assert named_by_focus(found, cfg) and explains_gap(found, *lim)
    noise = {"effect": "noise", "closeness": 0.133, "closeness_ci": [0.133, 0.133], "image_closeness": 0.2,
             "image_closeness_ci": [0.2, 0.2], "share_of_gap": -0.11, "ci_low": -0.2}
    top = Diagnosis._pick(None, [(noise, "noise"), (found, "focus")], cfg)
    assert top[1] == "focus" and top[0]["alternatives"] == []  # named before the closer effect, on its own evidence
    slightly_away = dict(found, image_closeness=-0.02)
    assert named_by_focus(slightly_away, cfg) and explains_gap(slightly_away, *lim)
    assert share_view(slightly_away)[0] == 1.0  # shown (clipped), not withheld as from a twin unlike the captures
    assert share_view(dict(found, effect="noise", image_closeness=-0.02))[0] is None
    untouched = _focus_entry("none", {"none": 0.87, "scale": 0.13}, rep, ci, **numbers)
    weak = _focus_entry("scale", {"none": 0.1, "scale": 0.9}, rep, ci, **numbers)
    for entry in (untouched, weak, dict(found, ci_low=-0.1), dict(found, image_closeness=-0.3),
                  dict(found, effect="noise")):
        assert not named_by_focus(entry, cfg)
    assert Diagnosis._pick(None, [(noise, "noise"), (untouched, "focus")], cfg)[1] == "noise"
    assert Diagnosis._pick(None, [(untouched, "focus")], cfg) is None
    # the interval with the estimates' systematic error, where the fit gives it, must exclude the reported focus too
    wide = _focus_entry("scale", {"scale": 1.0}, rep, ci, **numbers)
    wide["fit"]["corrected_focus"][0]["total_ci_m"] = [[0.55, 0.65], [1.9, 2.15], [5.5, 6.5]]
    assert not named_by_focus(wide, cfg) and not explains_gap(wide, *lim)
    # scene 2027's untouched copy (bench_diagnose_focus, code a0cf9db): its fit chose none in rounds 1 and 2 and a
    # 1.018 scale in round 3, after a phone pipeline (a stand-in) had joined the twin; correcting it closed 0.45 of
    # the gap. Not named on its measurement then: every earlier round's fit must have measured the error too.
    from aat_deploy.diagnose.search import focus_route

    earlier = [dict(untouched, round=1), dict(untouched, round=2), dict(noise, round=1)]
    assert not focus_route(earlier, cfg)
    assert Diagnosis._pick(None, [(noise, "noise"), (found, "focus")], cfg, focus_route(earlier, cfg))[1] == "noise"
    assert focus_route([dict(found, round=1), dict(noise, round=1)], cfg) and focus_route([], cfg)
    late = dict(found, round=3, focus_route=False)  # as _greedy marks it: the verdict does not count it either
    assert not named_by_focus(late, cfg) and not explains_gap(late, *lim)
    # no significant gap (the image-only search, no share): the measurement alone lists it
    assert named_by_focus(dict(found, share_of_gap=None, ci_low=None), cfg)
    assert not named_by_focus(dict(untouched, share_of_gap=None, ci_low=None), cfg)


def test_alternatives_are_the_effects_the_images_cannot_tell_apart():
    """_pick names the closest effect and lists the others that pass the rule with overlapping intervals."""
    from aat_deploy.diagnose.search import DiagnoseConfig, Diagnosis

    def e(name, clo, ci, img=None):
        return ({"effect": name, "closeness": clo, "closeness_ci": ci, "image_closeness": img or clo,
                 "image_closeness_ci": ci}, name)

    best = [e("lens_tolerance", 0.40, [0.30, 0.50]), e("sensor_tilt", 0.45, [0.35, 0.55]),
            e("noise", 0.10, [0.06, 0.14]), e("exposure", 0.02, [-0.1, 0.1])]
    top = Diagnosis._pick(None, best, DiagnoseConfig())
    assert top[1] == "sensor_tilt" and top[0]["alternatives"] == ["lens_tolerance"]
    assert Diagnosis._pick(None, [e("exposure", 0.02, [-0.1, 0.1])], DiagnoseConfig()) is None


def test_effect_entries_have_one_typed_constructor():
    """The search builds every entry of `effects_evaluated` through search.EffectEntry: the three kinds keep the
    keys (and their order) diagnosis.json has always had; fields never set are left out, None stays null."""
    from aat_deploy.diagnose.search import EffectEntry

    scored = EffectEntry("noise", {"sigma": 0.01}, 1, 0.3, [0.2, 0.4], 0.25, [0.1, 0.3], 0.05, [0.0, 0.1], 0.5,
                         0.4, 0.6, distances=[{"focus_curves": 0.1}], fit={"r": 1}).as_dict()
    assert list(scored) == ["effect", "params", "round", "closeness", "closeness_ci", "image_closeness",
                            "image_closeness_ci", "brightness_closeness", "brightness_closeness_ci", "share_of_gap",
                            "ci_low", "ci_high", "distances", "fit"]
    screened = EffectEntry("vignetting", {}, 2, -0.1, [-0.2, 0.0], -0.1, [-0.2, 0.0], 0.0, screened_out=True,
                           fit={}, note="not scored").as_dict()
    assert list(screened) == ["effect", "params", "round", "closeness", "closeness_ci", "image_closeness",
                              "image_closeness_ci", "brightness_closeness", "share_of_gap", "ci_low", "ci_high",
                              "screened_out", "fit", "note"]
    assert screened["share_of_gap"] is None and screened["ci_low"] is None
    none_found = EffectEntry("focus_metadata", None, 1, None, screened_out=True, fit={}, note="no setting").as_dict()
    assert list(none_found) == ["effect", "params", "round", "closeness", "share_of_gap", "ci_low", "ci_high",
                                "screened_out", "fit", "note"]
    grid = EffectEntry("noise", {}, 1, 0.3, [0.2, 0.4], 0.3, [0.2, 0.4], 0.0, [0.0, 0.0], None, None, None,
                       distances=[]).as_dict()
    assert "fit" not in grid and "screened_out" not in grid and grid["share_of_gap"] is None


def test_candidate_settings_are_chosen_on_images_and_only_the_closest_is_scored(setup):
    """`Diagnosis._best_of` compares an effect's candidate settings on their images alone and runs the model on the
    closest only (issue 32's speed): the setting and the scored twin are those of scoring every candidate and
    keeping the one whose images come closest, as before."""
    from aat_deploy.diagnose.inputs import find_captures, load_capture_data
    from aat_deploy.diagnose.lookup import find_lens
    from aat_deploy.diagnose.search import DiagnoseConfig, Diagnosis
    from aat_deploy.diagnose.session import make_renderer
    from aat_deploy.infer.model import DfFModel
    from aat_deploy.render import effects as fx

    tmp, model_path, sets = setup
    model = DfFModel(model_path, threads=2)
    twins = make_renderer(model, find_lens(model, RF50)[0], None, torch_free=True)
    diag = Diagnosis(model, twins, [load_capture_data(f, model) for f in find_captures(sets["none"])],
                     DiagnoseConfig(search="grid"))
    base = diag.score_twin([])
    settings = fx.make("noise").candidates
    every = [diag.score_twin([fx.make("noise", **p)]) for p in settings]
    want = min(every, key=lambda s: diag._image_distance(s.dist))
    calls = []
    infer = model.infer
    model.infer = lambda *a, **k: calls.append(1) or infer(*a, **k)
    got = diag._best_of("noise", settings, base, 0)
    assert got.effects[-1].params == want.effects[-1].params
    assert len(calls) == len(diag.runs)  # the model ran on the chosen setting's twins only
    for a, b in zip(got.pred, want.pred):
        assert np.array_equal(a, b)
    assert [dataclasses.asdict(d) for d in got.dist] == [dataclasses.asdict(d) for d in want.dist]


def test_report_marks_undetermined_frames_with_their_interval():
    """The focus section shows each corrected distance with its interval, systematic error included
    (`total_ci_m`), and marks a frame the fit left undetermined (`focusfit.UNDETERMINED_SD_D`) as such."""
    from aat_deploy.diagnose.report import focus_section

    f = {"family": "quantisation", "params": {"map_d": [1.7, 1.66]}, "params_ci": {}, "named": True,
         "explains_gap": True, "support": {"quantisation": 1.0},
         "families": [{"family": "quantisation", "k": 8, "score": 1.0}],
         "corrected_focus": [{"capture": "c", "reported_m": [0.588, 1.0], "corrected_m": [0.585, 1.0],
                              "ci_m": [[0.583, 0.588], [0.99, 1.01]], "total_ci_m": [[0.57, 0.61], [0.98, 1.02]],
                              "undetermined": [True, False]}]}
    text = "\n".join(focus_section({"focus": f}))
    assert "0.585 (0.570 … 0.610) **undetermined**" in text and "1.000 (0.980 … 1.020)," not in text
    assert "1.000 (0.980 … 1.020) |" in text and "1 frame(s) **undetermined**" in text
    f["corrected_focus"][0]["undetermined"] = [False, False]
    assert "undetermined" not in "\n".join(focus_section({"focus": f}))


def test_corrected_capture_json_only_when_the_diagnosis_names_a_measured_focus_error(tmp_path):
    """The drop-in corrected capture.json is written only when the diagnosis recommends it
    (`verdict.correction_advice`): focus metadata named AND its fit's evidence measured an error. Issue 32, scene
    2038's untouched copy: the first round's fit chose `monotone` (corrected up to 0.044 D off) while the whole
    diagnosis named noise and vignetting, not focus metadata; the old code wrote that capture.json anyway, making
    right distances worse. Then the report shows the fit's distances marked not recommended, with the reason."""
    from aat_deploy.diagnose.report import focus_section, write_focus_corrections
    from aat_deploy.diagnose.verdict import focus_summary

    def entry(support):
        fit = {"focus_fit": {"family": "monotone", "params": {"map_d": [1.7, 1.6]}, "params_ci": {},
                             "support": support, "families": [{"family": "monotone", "k": 3, "score": 1.0}]},
               "corrected_focus": [{"capture": "c", "files": ["f0.dng", "f1.dng"], "reported_m": [0.6, 6.0],
                                    "corrected_m": [0.62, 5.2], "ci_m": [[0.61, 0.63], [5.0, 5.4]],
                                    "total_ci_m": [[0.61, 0.63], [5.0, 5.4]], "undetermined": [False, False]}]}
        return {"effect": "focus_metadata", "round": 1, "fit": fit, "explains_gap": True}

    sure = {"monotone": 1.0, "none": 0.0}
    # not named (2038's untouched copy): nothing written, the report says why
    f = focus_summary([entry(sure)], [{"effect": "noise"}, {"effect": "vignetting"}])
    assert f["family"] == "monotone" and not f["named"] and not f["corrected_recommended"]
    assert "does not name focus metadata" in f["corrected_note"]
    assert write_focus_corrections(tmp_path / "a", {"focus": f}) == []
    assert not (tmp_path / "a" / "corrected_focus").exists()
    text = "\n".join(focus_section({"focus": f}))
    assert "**not recommended" in text and "corrected_focus/<capture>/" not in text
    assert "0.620 (0.610 … 0.630)" in text  # the fit's distances are still shown
    # named, but the fit's own evidence does not hold (an error family in too few replicates): nothing written
    weak = entry({"monotone": 0.7, "none": 0.3})
    f = focus_summary([weak], [weak])
    assert f["named"] and not f["corrected_recommended"] and "70%" in f["corrected_note"]
    assert write_focus_corrections(tmp_path / "b", {"focus": f}) == []
    # named and measured: written, and the report points to it
    good = entry(sure)
    f = focus_summary([good], [good])
    assert f["corrected_recommended"] and f["corrected_note"] is None
    (path,) = write_focus_corrections(tmp_path / "c", {"focus": f})
    assert [x["focus_m"] for x in json.loads(path.read_text())["frames"]] == [0.62, 5.2]
    assert "corrected_focus/<capture>/" in "\n".join(focus_section({"focus": f}))
