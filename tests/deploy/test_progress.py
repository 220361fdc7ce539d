"""The one progress reporter (aat_deploy.progress): stderr only, silent when quiet, a line per step without tqdm."""

from __future__ import annotations

import sys

from aat_deploy.progress import Progress, say, track


def test_quiet_says_nothing(capsys):
    bar = Progress(3, "x", quiet=True)
    for _ in range(3):
        bar.step("a")
    bar.note("kept")  # a note is a result line (a failure): printed even when quiet
    bar.close()
    say(True, "stage")
    assert list(track(range(4), 4, "t", quiet=True)) == [0, 1, 2, 3]
    out = capsys.readouterr()
    assert out.out == "" and out.err == "kept\n"


def test_lines_without_tqdm_and_bars_with_it(capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "tqdm", None)  # `from tqdm import tqdm` raises ImportError
    bar = Progress(2, "aat-eval", "run")
    bar.step("cap_a (m)")
    bar.step("cap_b (m)")
    bar.close()
    assert capsys.readouterr().err.splitlines() == ["aat-eval [1/2] cap_a (m)", "aat-eval [2/2] cap_b (m)"]
    monkeypatch.delitem(sys.modules, "tqdm")
    tiles = Progress(None, "tiles", "tile", leave=False)  # opened by the first callback, as DfFModel.infer calls it
    for done in range(1, 5):
        tiles(done, 4)
    assert tiles.done == 4 and tiles.bar is None and tiles.total == 4
    say(False, "writing")
    err = capsys.readouterr()
    assert err.out == "" and "  writing" in err.err and "0/4" in err.err  # the bar opened at the first tile, on stderr
