"""Sim-to-real diagnosis, the training-side half: the torch simulator behind the torch-free twin renderer, for
effects numpy cannot render (`chromatic` without per-wavelength surrogates, the lens's PSFs without a surrogate). The diagnosis itself is
`aat_deploy.diagnose`."""
