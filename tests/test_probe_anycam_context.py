"""probes/anycam_context and anycam_errmap: argument checks made before any export or render."""

import pytest

from benchmarks.probes import anycam_context, anycam_errmap


def test_context_refuses_even_windows_and_missing_checkpoints(tmp_path, capsys):
    ck = tmp_path / "last.pt"
    ck.write_bytes(b"")
    with pytest.raises(SystemExit):
        anycam_context.main([str(ck), "--windows", "0,8", "--out", str(tmp_path / "o")])
    assert "odd positive sizes or 0, got [8]" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        anycam_context.main([str(tmp_path / "none.pt"), "--out", str(tmp_path / "o")])
    assert "none.pt: no such checkpoint" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_errmap_never_overwrites(tmp_path, capsys):
    out = tmp_path / "fig.png"
    out.write_bytes(b"mine")
    with pytest.raises(SystemExit):
        anycam_errmap.main(["--model", str(tmp_path / "m.onnx"), "--out", str(out)])
    assert "fig.png: exists" in capsys.readouterr().err
    assert out.read_bytes() == b"mine"
