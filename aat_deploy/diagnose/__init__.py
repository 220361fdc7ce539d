"""Sim-to-real gap diagnosis, the torch-free half: capture inputs at the model's geometry, per-pixel covariates
and bins, bootstrap confidence intervals, image statistics that compare a capture with its digital twin, and
the report, the search over effects (`search.py`) and the command's run (`session.py`). Twins are rendered by
`aat_deploy.twin` (torch-free), with the training simulator behind it for torch-only effects when installed."""
