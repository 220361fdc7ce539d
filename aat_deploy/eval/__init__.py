"""Batch evaluation against ground truth (`aat-eval`) and ground truth rendered from a mesh (`aat-gt`)."""
