"""Held-out test sets (training/train/testsets.py): cached by content, the two focus protocols, Middlebury."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import LENSES

from training.train.testsets import TestSetSpec, load_test_set


@pytest.fixture(scope="module")
def small_lens(tmp_path_factory):
    """The RF50 on a 96 x 64 px sensor (same 36 x 24 mm), so whole-sensor stacks render in a blink."""
    d = json.loads((LENSES / "canon_rf50mm_f1.8.json").read_text())
    d["sensor"].update(width_px=96, height_px=64)
    p = tmp_path_factory.mktemp("lens") / "rf50_small.json"
    p.write_text(json.dumps(d))
    return str(p)


def _spec(lens, protocol, n=3):
    return TestSetSpec(lens, None, 5, protocol=protocol, n_procedural=n, simulator="thin_lens")


def test_cached_and_identical_on_reload(small_lens, tmp_path):
    a = load_test_set(_spec(small_lens, "fixed"), str(tmp_path), progress=False)
    assert list(tmp_path.rglob("*.npz"))  # written once ...
    b = load_test_set(_spec(small_lens, "fixed", n=2), str(tmp_path), progress=False)  # ... and read back
    assert len(a["procedural"]) == 3 and len(b["procedural"]) == 2
    for x, y in zip(a["procedural"][:2] + a["middlebury"], b["procedural"] + b["middlebury"]):
        assert x.stack.shape == (5, 3, 64, 96) and x.aif.shape == (3, 64, 96) and x.depth_m.shape == (64, 96)
        np.testing.assert_array_equal(x.stack, y.stack)  # float16 cache on both sides
        np.testing.assert_array_equal(x.focus_m, y.focus_m)


def test_protocols(small_lens, tmp_path):
    fixed = load_test_set(_spec(small_lens, "fixed"), str(tmp_path), progress=False)
    paper = load_test_set(_spec(small_lens, "paper"), str(tmp_path), progress=False)
    inv = np.linspace(1 / 0.5, 1 / 10.0, 5)
    for it in fixed["procedural"] + fixed["middlebury"]:
        np.testing.assert_allclose(it.focus_m, 1 / inv, rtol=1e-6)  # the camera-like schedule, scene-blind
    for it in paper["procedural"] + paper["middlebury"]:
        d = it.depth_m[it.depth_m > 0]
        step = (d.max() - d.min()) / 4
        assert np.all(np.diff(it.focus_m) > 0)
        assert it.focus_m[0] >= d.min() - 0.26 * step and it.focus_m[-1] <= d.max() + 0.26 * step
    mb = paper["middlebury"][0].depth_m
    assert 2.0 < mb[mb > 0].min() and mb.max() < 5.2  # Motorcycle spans 2.1-5.0 m


def test_effects_render_seeded_and_apart(small_lens, tmp_path):
    """Capture effects on a test set: a different cache entry, the same stack on every render (seeded noise,
    Middlebury too), and not the effect-free stack."""
    clean = load_test_set(_spec(small_lens, "fixed", n=1), str(tmp_path), progress=False)
    noisy_spec = TestSetSpec(small_lens, None, 5, n_procedural=1, simulator="thin_lens", effects=("noise",))
    a = load_test_set(noisy_spec, str(tmp_path / "a"), progress=False)
    b = load_test_set(noisy_spec, str(tmp_path / "b"), progress=False)  # rendered afresh elsewhere
    assert noisy_spec.key() != _spec(small_lens, "fixed", n=1).key()
    for s in ("procedural", "middlebury"):
        np.testing.assert_array_equal(a[s][0].stack, b[s][0].stack)
        assert np.abs(a[s][0].stack - clean[s][0].stack).mean() > 1e-3
        np.testing.assert_array_equal(a[s][0].depth_m, clean[s][0].depth_m)


def test_key_without_effects_is_unchanged():
    """Adding the `effects` field must not invalidate the test sets already rendered (hash of the RF50 set before
    the field existed)."""
    spec = TestSetSpec("lenses/canon_rf50mm_f1.8.json", "models/psf_rf50.onnx", 8)
    assert spec.key() == "23d99424ccfa"


def test_validation_split_is_apart_from_the_test_set(small_lens, tmp_path):
    """photo_split="train" (the validation sets settings are chosen on): its own cache entry and other scenes;
    the test set's key is unchanged by the field; an unknown split is refused."""
    test = _spec(small_lens, "fixed", n=1)
    val = TestSetSpec(small_lens, None, 5, n_procedural=1, simulator="thin_lens", photo_split="train", seed=1)
    assert val.key() != test.key()
    a = load_test_set(test, str(tmp_path), progress=False)["procedural"][0]
    b = load_test_set(val, str(tmp_path), progress=False)["procedural"][0]
    assert np.abs(a.aif - b.aif).mean() > 1e-3
    assert TestSetSpec("lenses/canon_rf50mm_f1.8.json", "models/psf_rf50.onnx", 8, photo_split="test").key() \
        == "23d99424ccfa"
    with pytest.raises(ValueError, match="photo_split"):
        TestSetSpec(small_lens, None, 5, photo_split="val")


def test_field_focus_sets_are_rendered_again_after_the_renderer_fix():
    """Sets whose effects vary focus over the field (sensor_tilt, lens_tolerance) were drawn wrong before c9c07bd
    (every anchor at the first anchor's cell size): their keys changed, so stale cached renders are not read. Sets
    the fix did not touch keep their keys (hashes before the mark existed)."""
    def key(*effects):
        return TestSetSpec("lenses/canon_rf50mm_f1.8.json", "models/psf_rf50.onnx", 8, effects=effects).key()

    assert key("noise") == "a6092bfe0a28" and key("noise", "vignetting") == "0caf85be2564"
    assert key("sensor_tilt") != "9df47c43eb63" and key("noise", "lens_tolerance") != "a66a37ef1780"
    assert key("sensor_tilt") != key("sensor_tilt:tilt_x_deg=0.2")  # settings still count


def test_varies_focus_follows_the_effects_hooks():
    """The mark follows the effects' own hooks (focus_at / sensor_shift_mm), not a list of names."""
    from aat_deploy.render import effects as fx
    from aat_deploy.render.effects.registry import _REGISTRY, _load

    _load()
    varying = {n for n, cls in _REGISTRY.items() if fx.varies_focus([cls()])}
    assert {"sensor_tilt", "lens_tolerance"} <= varying
    assert not {"noise", "vignetting", "raw_pipeline", "focus_metadata"} & varying


def test_a_lens_file_corrected_in_place_is_refused_for_the_middlebury_item(small_lens, tmp_path):
    """The key holds the lens path, not its contents: the set's cache folder records the file's SHA-256, and even a
    set of the Middlebury item alone (no procedural item read) refuses a cache rendered with the old file."""
    lens = tmp_path / "lens.json"
    lens.write_text(open(small_lens).read())
    spec = _spec(str(lens), "fixed", n=0)
    load_test_set(spec, str(tmp_path / "c"), progress=False)
    assert list((tmp_path / "c").glob("middlebury_*.npz")) and list((tmp_path / "c").glob("*/sources.json"))
    load_test_set(spec, str(tmp_path / "c"), progress=False)  # unchanged: read back
    (record,) = (tmp_path / "c").glob("*/sources.json")
    saved = record.read_bytes()
    record.unlink()  # a set rendered before the record: its Middlebury file makes the folder unverified, unstamped
    load_test_set(spec, str(tmp_path / "c"), progress=False)
    assert not record.exists()
    record.write_bytes(saved)
    lens.write_text(lens.read_text() + " ")
    with pytest.raises(ValueError, match=r"rendered from lens .*lens.json.*fresh --cache"):
        load_test_set(spec, str(tmp_path / "c"), progress=False)


def test_registry_scenes_change_the_key_only_when_asked_for():
    base = TestSetSpec("lenses/canon_rf50mm_f1.8.json", "models/psf_rf50.onnx", 8)
    assert TestSetSpec("lenses/canon_rf50mm_f1.8.json", "models/psf_rf50.onnx", 8, registry_real=()).key() == base.key()
    assert TestSetSpec("lenses/canon_rf50mm_f1.8.json", "models/psf_rf50.onnx", 8,
                       registry_real=("aloe",)).key() != base.key()
    with pytest.raises(ValueError, match=r"registry_real must name scenes of \('aloe', 'arc2017'\), got 'alo'"):
        TestSetSpec("lenses/canon_rf50mm_f1.8.json", "models/psf_rf50.onnx", 8, registry_real=("aloe", "alo"))
