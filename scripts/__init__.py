"""Scripts that regenerate shipped data (the glass catalogue, the thin-lens baseline, the sample capture, the
README's and docs' pictures), train and export the shipped models, and check the tree (`import_graph`,
`output_fingerprints`).

Run each from the repository root as a module, `python -m scripts.NAME [...]`, so that `aat_deploy` and `training`
import from this checkout; no script edits `sys.path` (tests/test_benchmarks_layout.py).
"""
