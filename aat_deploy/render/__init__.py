"""Rendering focal stacks, torch-free: the simulator's effects (`effects/`, one file each), the layered renderer
over numpy or torch arrays (`layered.py`; torch's backend is registered by `training.render.layered`), a stack
through the lens (`optical.py`) and PSF sources (`sources.py`: the exported ONNX surrogate, the thin-lens
Gaussian); pixels' field positions are optics (`aat_deploy.optics.field`). The torch simulator
(`training.render.simulator`) and the digital twins (`aat_deploy.diagnose.twin`) are both built from these."""
