"""The main job's room: a focal stack to depth, all-in-focus and uncertainty.

`method` declares what every depth method is to the runtime (`DepthMethod`, `DepthOutput`): the classical focus
method (`aat_deploy.focus.runner.FocusMethod`), the lens-specific ONNX DfF model (`aat_deploy.infer.model.DfFModel`) and
the any-camera model (`aat_deploy.anycam.model.FocusMapModel`) implement it.
"""
