"""aat runtime: reads capture folders, runs ONNX depth-from-focus, writes results. Never imports torch."""
