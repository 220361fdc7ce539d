#!/usr/bin/env bash
# Issue 20's models (the paper's Table 2 on its own lens and on the RF50): configs/table2/*.json.
# Each pair (AAT and its thin-lens twin, identical but for the simulator) trains concurrently, one torch thread
# each (on 2 cores a second thread barely speeds a small net up, a second run doubles throughput). Resumable:
# rerun after a kill and every run continues from $OUT/<name>/last.pt; finished runs are skipped. Training data
# is rendered once into cache/stacks (scripts/render_training_stacks.py) and shared by the nets of one lens.
#   OUT=cache/runs/table2 nice -n 10 scripts/train_table2.sh [NAME_AAT NAME_THIN ...]
# then: python -m scripts.export_dff_models --runs cache/runs/table2 NAME ...   (models/NAME.onnx; --out models/reproduce for baselines and ablations)
# A run whose folder is missing (a new machine) starts from its committed checkpoint in checkpoints/table2/NAME/
# (scripts/snapshot_runs.sh copies the unfinished runs' last.pt and logs there at the end of a session).
# A run already shipped as models/NAME.onnx (and not in progress in $OUT) is skipped, with its data rendering.
set -euo pipefail
cd "$(dirname "$0")/.."
export OMP_WAIT_POLICY=PASSIVE OMP_NUM_THREADS=1 PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
OUT=${OUT:-cache/runs/table2}
mkdir -p "$OUT"
pairs=("$@")
if [ ${#pairs[@]} -eq 0 ]; then
  # two runs at a time: the RF50 DFVNet pair right after the paper lens's pairs (the shipped lens's models), then
  # the field-aware DFVNets (the paper lens's AAT DFVNet trades centre for field: BENCHMARKS, "The paper's
  # Table 2 on its own lens"), the RF50 AiFNets, the paper-lens AiFNets fine-tuned with an all-in-focus loss
  # (Table 3; they start from models/reproduce/paper50_aifnet_*.onnx), then the field-aware AiFNets
  pairs=(paper50_dfvnet_aat paper50_dfvnet_thin paper50_aifnet_aat paper50_aifnet_thin
         rf50_dfvnet_aat rf50_dfvnet_thin paper50_dfvnet_aat_field rf50_dfvnet_aat_field
         rf50_aifnet_aat rf50_aifnet_thin paper50_aifnet_aat_aif paper50_aifnet_thin_aif
         paper50_aifnet_aat_field rf50_aifnet_aat_field)
fi
for ((i = 0; i < ${#pairs[@]}; i += 2)); do
  names=("${pairs[i]}")
  [ $((i + 1)) -lt ${#pairs[@]} ] && names+=("${pairs[i + 1]}")
  todo=() cfgs=()
  for n in "${names[@]}"; do
    if [ -f "$OUT/$n/model.pt" ]; then echo "$n: done"; continue; fi
    # shipped and not being trained here: a new machine does not train it again
    if [ -f "models/$n.onnx" ] && [ ! -f "$OUT/$n/last.pt" ]; then echo "$n: shipped as models/$n.onnx"; continue; fi
    todo+=("$n") cfgs+=("configs/table2/$n.json")
  done
  [ ${#todo[@]} -eq 0 ] && continue
  python -m scripts.render_training_stacks "${cfgs[@]}" --workers 2
  pids=()
  for n in "${todo[@]}"; do
    if [ ! -f "$OUT/$n/last.pt" ] && [ -f "checkpoints/table2/$n/last.pt" ]; then
      mkdir -p "$OUT/$n" && cp checkpoints/table2/"$n"/* "$OUT/$n/" && echo "$n: resumed from checkpoints/table2/$n"
    fi
    python -m training.cli.train --config "configs/table2/$n.json" --out "$OUT/$n" --resume --no-progress \
      >> "$OUT/$n.log" 2>&1 &
    pids+=($!)
  done
  for p in "${pids[@]}"; do wait "$p"; done
done
