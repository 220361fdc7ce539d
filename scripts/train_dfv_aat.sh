#!/usr/bin/env bash
# Issue 35's any-camera model (models/dfv_aat.onnx): configs/anycam/NAME.json (default dfv_aat), one run, resumable.
#   OUT=cache/runs nice -n 15 scripts/train_dfv_aat.sh [NAME]   (rerun the same command to continue after a kill)
# then: python -m scripts.export_dff_models --runs cache/runs dfv_aat   (models/dfv_aat.onnx)
# Training data is rendered once into cache/stacks (python -m scripts.render_training_stacks configs/anycam/dfv_aat.json,
# under the heavy-job lock); items still missing when the run reads them are rendered by the run itself and cached.
# A run whose folder is missing (a new machine) starts from its committed checkpoint in checkpoints/dfv_aat/
# (DEST=checkpoints OUT=cache/runs scripts/snapshot_runs.sh copies last.pt and the logs there).
set -euo pipefail
cd "$(dirname "$0")/.."
export OMP_WAIT_POLICY=PASSIVE OMP_NUM_THREADS=1 PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
OUT=${OUT:-cache/runs}
n=${1:-dfv_aat}
[ -f "configs/anycam/$n.json" ] || { echo "configs/anycam/$n.json: no such config" >&2; exit 2; }
mkdir -p "$OUT"
if [ -f "$OUT/$n/model.pt" ]; then echo "$n: done ($OUT/$n/model.pt)"; exit 0; fi
if [ ! -f "$OUT/$n/last.pt" ] && [ -f "checkpoints/$n/last.pt" ]; then
  mkdir -p "$OUT/$n" && cp checkpoints/"$n"/* "$OUT/$n/" && echo "$n: resumed from checkpoints/$n"
fi
# a run killed from outside (the machine's memory is shared: the OOM killer) resumes from its last checkpoint
# (not one refused for its inputs, exit 2: a changed lens/PSF file under the renders, a bad config)
for attempt in $(seq 1 ${RETRIES:-20}); do
  rc=0
  python -m training.cli.train --config configs/anycam/$n.json --out "$OUT/$n" --resume --no-progress \
    >> "$OUT/$n.log" 2>&1 || rc=$?
  [ "$rc" -eq 0 ] && exit 0
  [ -f "$OUT/$n/model.pt" ] && exit 0
  if [ "$rc" -eq 2 ]; then echo "$n: refused: $(tail -n 1 "$OUT/$n.log")" >&2; exit 2; fi
  echo "$n: attempt $attempt failed ($(date)); resuming in 60 s" >> "$OUT/$n.log"
  sleep 60
done
exit 1
