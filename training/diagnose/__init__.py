"""Sim-to-real diagnosis, the training-side half: digital twins of real captures rendered with the simulator a
model was trained with, effects added one at a time, and the orchestration (`run.py`). The statistics are in
`aat_deploy.diagnose` (torch-free)."""
