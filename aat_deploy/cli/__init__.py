"""Command-line tools of the runtime: aat-capture, aat-infer, aat-view."""
