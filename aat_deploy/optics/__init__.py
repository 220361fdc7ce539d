"""First-order optics without ray tracing (numpy only): paraxial data (`paraxial.py`). Real-ray tracing, which
needs torch, is `training.optics`."""
