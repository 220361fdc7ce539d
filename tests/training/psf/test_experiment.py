"""PSF fit checkpoints are keyed by what the fit depends on, so configs never resume each other's fits."""

import dataclasses
import json

from aat_deploy.lens.io import load_lens, save_lens
from training.psf.experiment import PSFExperiment


def _config(folder, sensor_mm, minutes=4.0):
    folder.mkdir(parents=True, exist_ok=True)
    lens = load_lens("lenses/canon_rf50mm_f1.8.json")
    sensor = dataclasses.replace(lens.sensor, width_mm=sensor_mm[0], height_mm=sensor_mm[1], width_px=288, height_px=192)
    save_lens(dataclasses.replace(lens, sensor=sensor), folder / "lens.json", force=True)
    (folder / "psf.json").write_text(json.dumps({"lens": str(folder / "lens.json"), "train_axis": {"n": 10},
                                                 "fits": {"rot": {"minutes": minutes}}}))
    return PSFExperiment.load(folder / "psf.json")


def test_same_file_name_other_sensor_gets_its_own_checkpoint(tmp_path):
    full = _config(tmp_path / "full", (36.0, 24.0))
    crop = _config(tmp_path / "crop", (9.0, 6.0))
    a, b = full.checkpoint("rot", tmp_path), crop.checkpoint("rot", tmp_path)
    assert a != b and a.name.startswith("psf_rot_") and b.name.startswith("psf_rot_")
    # the same config gives the same checkpoint (a stopped fit resumes), an edited fit setting does not
    assert _config(tmp_path / "full", (36.0, 24.0)).checkpoint("rot", tmp_path) == a
    assert _config(tmp_path / "full", (36.0, 24.0), minutes=8.0).checkpoint("rot", tmp_path) != a
    # the lens passed in (as the fit gets it) and the lens the config names give the same key
    assert full.checkpoint("rot", tmp_path, full.lens_obj()) == a
