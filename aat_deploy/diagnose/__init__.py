"""Sim-to-real gap diagnosis, the torch-free half: capture inputs at the model's geometry, per-pixel covariates
and bins, bootstrap confidence intervals, image statistics that compare a capture with its digital twin, and
the report. The twins themselves are rendered by the training simulator (`training.diagnose`)."""
