"""The old import path of `aat_deploy.infer.model` (the ONNX DfF model), kept because users' code imports
`aat_deploy.model.DfFModel`; new code imports `aat_deploy.infer.model`."""

from .infer.model import CONTRACT_RANK, REQUIRED_META, SUMMARY_META, DfFModel

__all__ = ["CONTRACT_RANK", "REQUIRED_META", "SUMMARY_META", "DfFModel"]
