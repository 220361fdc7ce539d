"""Depth-from-focus networks (AiFNet, DFVNet), the shared softmax head, input normalisation and ONNX export."""
