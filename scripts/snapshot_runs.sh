#!/usr/bin/env bash
# Copy the unfinished Table 2 runs' checkpoints (last.pt, log.jsonl, config.json) into checkpoints/table2/ so a
# later session on another machine resumes them (scripts/train_table2.sh restores from there); finished runs are
# shipped as ONNX instead and their snapshot is removed.   OUT=cache/runs/table2 scripts/snapshot_runs.sh
# Other runs: DEST names the folder (the any-camera run: DEST=checkpoints OUT=cache/runs, scripts/train_dfv_aat.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-cache/runs/table2}
DEST=${DEST:-checkpoints/table2}
for d in "$OUT"/*/; do
  n=$(basename "$d")
  if [ -f "$d/model.pt" ]; then rm -rf "${DEST:?}/$n"; continue; fi
  [ -f "$d/last.pt" ] || continue
  mkdir -p "$DEST/$n"
  cp "$d/last.pt" "$d/log.jsonl" "$d/config.json" "$DEST/$n/"
  echo "$n: step $(python -c "import torch,sys; print(torch.load(sys.argv[1], weights_only=False)['step'])" "$d/last.pt")"
done
