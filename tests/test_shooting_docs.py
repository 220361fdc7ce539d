"""docs/shooting.md holds what the code prints: the per-brand focus-distance tables are the output of
benchmarks/exif_focus_table.py (not typed by hand) and the stack plan is aat-capture plan's."""

from __future__ import annotations

import re

import pytest
from conftest import ROOT, SHARED

from aat_deploy.capture import exiftool
from aat_deploy.cli import capture as cli

DOC = ROOT / "docs" / "shooting.md"


def _table_module():
    from benchmarks import exif_focus_table

    return exif_focus_table


def test_brand_tables_are_the_scripts_output():
    folder = SHARED / "raw_exif_makernotes_exiftool"
    if not folder.is_dir():
        pytest.skip(f"{folder} not present (a user's clone has no ../shared/data)")
    if not exiftool.available():
        pytest.skip("exiftool not installed (Debian libimage-exiftool-perl; .ci/run installs it)")
    m = re.search(r"<!-- begin: python -m benchmarks.exif_focus_table -->\n(.*?)\n<!-- end", DOC.read_text(), re.S)
    assert m, "the generated block is missing from docs/shooting.md"
    assert m.group(1) == _table_module().tables(folder), \
        "docs/shooting.md is out of date: paste the output of python -m benchmarks.exif_focus_table"


def test_brands_without_a_recorded_focus_distance_are_as_the_docs_say():
    folder = SHARED / "raw_exif_makernotes_exiftool"
    if not folder.is_dir():
        pytest.skip(f"{folder} not present (a user's clone has no ../shared/data)")
    rows = _table_module().rows(folder)
    none = {r["brand"] for r in rows} - {r["brand"] for r in rows if r["ours_ok"] or r["exiftool_ok"]}
    assert none == {"Sony", "Fujifilm", "Panasonic", "Pentax", "Apple", "Phase One", "Sigma"}
    said = DOC.read_text().split("So: ")[1].split("Then write")[0]
    assert all(b in said.split("for ")[1] for b in none)


def test_plan_example_is_the_commands_output(capsys):
    block = re.search(r"\$ aat-capture plan (.*?)\n(.*?)```", DOC.read_text(), re.S)
    assert block
    assert cli.main(["plan", *block.group(1).split()]) == 0
    assert capsys.readouterr().out == block.group(2)
