"""Ground truth: a capture folder's ground-truth depth found, read, checked and brought to the model's sensor
(`read.py`, used by `aat-eval`, `aat-infer` and `aat-gt check`); ground truth made from a mesh by ray casting from a
camera pose (`raycast.py`, `aat-gt render`) and that pose fitted to clicked points (`pose.py`, `aat-gt pose`);
holes in a depth map filled for rendering (`holes.py`)."""
