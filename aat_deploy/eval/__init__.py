"""Batch evaluation against ground truth (`aat-eval`): finding captures, running the models, scores, tables,
plots and the recording. Reading and making ground truth: `aat_deploy.gt`."""
