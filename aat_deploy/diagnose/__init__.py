"""Sim-to-real gap diagnosis (`aat-diagnose`), all of it, torch-free: capture inputs at the model's geometry
(`inputs.py`), digital twins of captures (`twin.py`: `TwinRenderer`; the lens and surrogate a model needs,
`lookup.py`; twins at reduced resolution, `binned.py`), per-pixel covariates and bins, bootstrap confidence
intervals, image statistics that compare a capture with its twin, the fits of effects' settings (`fitters.py`,
`focusfit.py`, `optimise.py`); the diagnosis's three steps: where the gap lies (`gap.py`), the search over effects
and the entry point (`search.py`: `diagnose`, one `EffectEntry` per effect tried), what it means and the verdict
(`verdict.py`); the report and the command's run (`session.py`). When the training package is installed, the torch simulator renders the effects numpy cannot
(`training.render.torch_twin`, the declared extension `torch_twin_renderer`)."""
