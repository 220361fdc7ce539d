"""benchmarks/probes/corner_tiles: its --out is never overwritten without --force and an unknown variant is one
line (nothing run, nothing written); the tiles it drops beyond the centred grid's radius are exactly those."""

from __future__ import annotations

import dataclasses

import numpy as np

from aat_deploy.calibrate.format import field_radius_of
from aat_deploy.calibrate.peaks import SweepPeaks, TileGrid
from benchmarks.probes import corner_tiles as ct


def test_out_is_kept_and_unknown_variants_are_refused(tmp_path, capsys):
    out = tmp_path / "c.json"
    out.write_text("{}")
    assert ct.main(["--out", str(out)]) == 2
    assert "exists" in capsys.readouterr().err and out.read_text() == "{}"
    assert ct.main(["--out", str(tmp_path / "d.json"), "--variants", "copy_s1_9x"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown variant" in err[0] and not (tmp_path / "d.json").exists()


def test_an_unknown_variant_late_in_the_list_is_refused_before_any_is_run(tmp_path, capsys, monkeypatch):
    ran = []
    monkeypatch.setattr(ct, "run", lambda v, log: ran.append(v) or {})
    assert ct.main(["--out", str(tmp_path / "d.json"), "--variants", "nominal,copy_s1_9x"]) == 2
    assert ran == [] and "copy_s1_9x" in capsys.readouterr().err and not (tmp_path / "d.json").exists()


def test_drop_beyond_uncounts_only_the_tiles_beyond_the_radius():
    grid = TileGrid(480, 640, 27, to_edges=True)
    why = np.full(grid.shape, "", dtype=object).astype(str)
    why[0, 1] = "flat"
    pk = SweepPeaks(grid, np.arange(3.0), np.zeros((3,) + grid.shape), np.zeros(grid.shape), why,
                    np.ones(grid.shape), np.zeros(grid.shape, np.int64))

    @dataclasses.dataclass
    class M:
        peaks: SweepPeaks

    (m,) = ct.drop_beyond([M(pk)], ct.CENTRED_RADIUS, 640 / 480)
    x, y = grid.field()
    far = field_radius_of(x, y, 640 / 480) > ct.CENTRED_RADIUS
    assert far.sum() == 4 and np.all(m.peaks.why[far] == "beyond")  # the four corner tiles, flush with the borders
    assert np.all(m.peaks.why[~far] == why[~far]) and np.all(pk.why == why)  # the rest as they were, the input kept
