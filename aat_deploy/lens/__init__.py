"""A lens as plain data: the prescription (`schema.py`), materials and the glass catalogue (`materials.py`,
`data/glasses.json`), and the file readers and writer (`io.py`: our JSON, the paper's JSON, Zemax, DiffOptics).
numpy only: the runtime and the training side read lenses with the same code."""
