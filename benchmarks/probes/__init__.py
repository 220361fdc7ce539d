"""Exploratory probes: they look at a weakness (often on test scenes) and print what they see, but choose nothing;
the choices are made by the selection scripts in `benchmarks/` on validation data. Run as
`python -m benchmarks.probes.NAME`."""
