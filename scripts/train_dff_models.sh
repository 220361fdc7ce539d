#!/usr/bin/env bash
# Retrain and re-export the four small DfF models shipped in models/ (AAT vs thin-lens, AiFNet and DFVNet).
# Resumable: rerun after a kill and each run continues from runs/<name>/last.pt. About 1 h on 2 CPU cores
# (the first pass over each simulator's data renders and caches it in cache/stacks).
set -euo pipefail
cd "$(dirname "$0")/.."
export OMP_WAIT_POLICY=PASSIVE
for name in dff_dfvnet_aat dff_dfvnet_thin dff_aifnet_aat dff_aifnet_thin; do
  aat-train --config "configs/${name}.json" --out "runs/${name}" --resume --no-progress
done
python -m scripts.export_dff_models --force --out models/reproduce  # the first models, superseded (models/README.md)
