"""Point spread functions without torch: how a PSF is stored (`kernel.py`: a k x k window whose cells grow with
the defocus blur) and the exported ONNX surrogate queried with onnxruntime (`surrogate.py`). Tracing and fitting
PSFs needs torch: `training.psf`."""
