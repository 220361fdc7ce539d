"""A lens as plain data: the prescription (`schema.py`), materials and the glass catalogue (`materials.py`,
`data/glasses.json`), its checks (`check.py`); the file readers and writer are the subfolder `io/` (our JSON, the
paper's JSON, Zemax, DiffOptics), which sits above `aat_deploy.optics`. numpy only: the runtime and the training side
read lenses with the same code."""
