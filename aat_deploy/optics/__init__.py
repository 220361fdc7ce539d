"""First-order optics without ray tracing (numpy only): paraxial data (`paraxial.py`), the pinhole camera of output
maps (`camera.py`). Real-ray tracing, which
needs torch, is `training.optics`."""
