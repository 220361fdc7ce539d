#!/usr/bin/env bash
# Issue 35: every measurement of parts 4 and 5 for one any-camera model, the commands BENCHMARKS.md lists
# ("Every measurement of parts 4 and 5 for the first run's net"), in one resumable script.
#   scripts/judge_anycam.sh MODEL.onnx LABEL [TILE]
# TILE: the side (px) dfv_aat runs in, 0 = whole frames; default the model's aat.tile_px. Choose it on validation
# stacks first (step 1 prints them), never on the test scenes below.
# Results: results/anycam_LABEL.json (+ _z35), results/runtime_anycam_LABEL.json, results/figures/anycam_real_LABEL.
# Every bench_anycam command skips the rows its results file already holds, so a rerun continues there after a kill
# (steps 1, 4 and 5 run again in full).
# LOCK=/path/to/lock runs each heavy command under that flock (a lane of a shared machine); one thread each.
# DRY=1 prints the commands instead of running them.
set -euo pipefail
[ $# -ge 2 ] || { echo "usage: scripts/judge_anycam.sh MODEL.onnx LABEL [TILE]" >&2; exit 2; }
[ -f "$1" ] || { echo "$1: no such model" >&2; exit 2; }
model=$(realpath "$1") label=$2
cd "$(dirname "$0")/.."
export OMP_WAIT_POLICY=PASSIVE OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
# bench_runtime's own default is the tile of configs/anycam/dfv_aat.json, so name the model's own one
tile=${3:-$(python -c "import onnxruntime as o, sys
print(o.InferenceSession(sys.argv[1]).get_modelmeta().custom_metadata_map.get('aat.tile_px', ''))" "$model")}
run() {
  if [ -n "${DRY:-}" ]; then echo "$*"; return; fi  # DRY=1: print the commands only
  if [ -n "${LOCK:-}" ]; then flock "$LOCK" nice -n 10 "$@"; else nice -n 10 "$@"; fi
}
# the speed row times a fresh net of the model's own size (its padding adds Pad nodes)
size=$(python -c "import onnxruntime as o, sys
print(o.InferenceSession(sys.argv[1]).get_modelmeta().custom_metadata_map.get('aat.size', 'small'))" "$model")
tile_arg=(); [ -n "$tile" ] && tile_arg=(--tile "$tile")
tiles=$(echo "$tile,0,256,128" | tr ',' '\n' | awk 'NF && !seen[$0]++' | paste -sd,)

# 1. validation only (RF50, training photographs, their own seed): the tile size to run in
run python -m benchmarks.probes.anycam_tiles --model "$model" --lens rf50 --split validation --n 12 \
  --tiles "$tiles" --threads 1 --json "results/anycam_${label}_tiles_validation.json"
# 2. the held-out lenses and the RF50, both protocols, 24 scenes each (+ the real RGB-D scenes)
B=(python -m benchmarks.bench_anycam --model "$model" --n 24 --threads 1 --label "$label" "${tile_arg[@]}")
for protocol in fixed paper; do
  run "${B[@]}" --lenses paper50 rf50 --protocol "$protocol"
  run "${B[@]}" --lenses ef50 --protocol "$protocol"
done
# the Z35's test stacks in a cache of their own (BENCHMARKS.md, "Nikon Z35")
for protocol in fixed paper; do
  run python -m benchmarks.bench_anycam --model "$model" --n 24 --threads 1 --label "${label}_z35" \
    --cache cache/heldout_z35 "${tile_arg[@]}" --lenses z35 --protocol "$protocol"
done
# 3. the stack-size and schedule tables (paper lens)
run "${B[@]}" --lenses --tables stack_size
run "${B[@]}" --lenses --tables schedule
# 4. speed against today's DfF net at the same size
run python -m benchmarks.bench_runtime --nets dfvnet,dfvaat --anycam-size "$size" --threads 1 "${tile_arg[@]}" \
  --json "results/runtime_anycam_${label}.json"
# 5. the real stacks: shown, not scored
run python -m scripts.make_real_gallery --model "$model" --methods focus,dfv_aat --stacks lytro_lightfield \
  --panel-px 160 --out "results/figures/anycam_real_${label}"
echo "judged $model as $label: results/anycam_${label}.json, results/anycam_${label}_z35.json"
