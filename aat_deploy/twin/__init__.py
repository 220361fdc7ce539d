"""Digital twins without torch: a capture's scene rendered through the exported PSF surrogate (ONNX) with the
same layered renderer and the same effects registry (`aat_deploy.render.effects`) as the training simulator.

- `fields.py`: normalised field positions of pixels;
- `layered.py`: the fast layered renderer (numpy port of `training.render.layered`);
- `sources.py`: PSF sources (the ONNX surrogate, the thin-lens Gaussian) and the unit-energy wrapper;
- `renderer.py`: `TwinRenderer`, twins of captures for one DfF model.

Only the retraining, ray-traced PSFs and the `chromatic` effect without per-wavelength surrogates need the training
package (torch).
"""
