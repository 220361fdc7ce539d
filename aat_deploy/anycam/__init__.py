"""The any-camera DfF model (`dfv_aat`) at run time: the camera's optics (`optics`: focal length, f-number, pixel
pitch from EXIF, `--camera`, a lens file or a calibration), the per-pixel maps it needs (`maps`: in-focus diopters
of every frame at every pixel and the defocus scale, from a thin lens, a lens's best-focus map or a calibration)
and the ONNX model that takes them (`model`). Torch-free."""
