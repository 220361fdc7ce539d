"""Depth-from-focus networks (AiFNet, DFVNet), the shared softmax head, the wrapper that is exported (`model.py`:
DfFNet), ONNX export (`export.py`) and starting from trained weights (`warm_start.py`). Input normalisation is the
runtime's (`aat_deploy.infer.normalise`)."""
