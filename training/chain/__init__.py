"""From a lens file to deployable, aberration-aware DfF models in one folder (`aat-train --lens ...`).

config.py     command-line options + preset -> the resolved config (DIR/config.json)
hashing.py    content hashes and stage records (what is up to date)
lens_check.py stage 1: the lens with your sensor, paraxial summary, image circle, warnings
stages.py     the stages (lens, psf, train_aat, train_thin, export, evaluate, report) and their inputs/outputs
runner.py     runs the stages: skip / resume / restart, torchrun coordination
report.py     DIR/report.md
"""
