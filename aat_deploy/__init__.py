"""aat runtime: reads capture folders, runs ONNX depth-from-focus, writes results. Never imports torch."""

__version__ = "0.1.0"
DISTRIBUTION = "aat-dff"  # the name on the package index ("aat" there is an unrelated package)
