#!/usr/bin/env bash
# Probe for the rotation head: does it learn the approach yaw (the one keyframe where the policy reads the yaw
# off the object) better when it also pools the full-resolution decoder features at the heatmap
# (--local-rotation-features) instead of the 12.5 cm patch tokens alone? Two abm trainings with oracle masks,
# identical but for that flag (same seed, data and recipe: configs/paper_tables.yaml), on the two tasks with
# the largest approach-yaw errors in the paper tables, side by side with one thread each; then the
# teacher-forced keyframe accuracy of both on seen and unseen objects. Result: docs/results/rotation_probe.md.
#
# Usage: bash scripts/rotation_probe.sh DATA [OUT]   (DATA: seen demonstrations of the tasks, e.g. runs/paper/data)
# Knobs: TASKS (place_food take_off_pan), STEPS (2000), EPISODES (10). Resumable (--resume; finished parts kept).
set -euo pipefail
cd "$(dirname "$0")/.."
[ -x .venv/bin/abm ] || bash scripts/bootstrap.sh
export PATH="$PWD/.venv/bin:$PATH" MUJOCO_GL="${MUJOCO_GL:-egl}" OMP_WAIT_POLICY="${OMP_WAIT_POLICY:-PASSIVE}"
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
DATA="$1"
OUT="${2:-runs/rotation_probe}"
TASKS="${TASKS:-place_food take_off_pan}"
STEPS="${STEPS:-2000}"
EPISODES="${EPISODES:-10}"
mkdir -p "$OUT"
pids=()
for name in tokens pixels; do
  flag=--no-local-rotation-features; [ "$name" = pixels ] && flag=--local-rotation-features
  # shellcheck disable=SC2086
  abm train --config paper_tables --method abm --grounder oracle --data "$DATA" --tasks $TASKS --steps "$STEPS" \
    "$flag" --no-progress --out "$OUT/$name" --resume > "$OUT/train_$name.log" 2>&1 &
  pids+=($!)
done
for p in "${pids[@]}"; do wait "$p"; done
pids=()
for name in tokens pixels; do
  [ -f "$OUT/keyframe_accuracy_$name.json" ] && continue
  # shellcheck disable=SC2086
  python benchmarks/keyframe_accuracy.py --run "$OUT/$name" --tasks $TASKS --splits seen unseen \
    --episodes "$EPISODES" --out "$OUT/keyframe_accuracy_$name.json" > "$OUT/keyframe_accuracy_$name.log" 2>&1 &
  pids+=($!)
done
for p in "${pids[@]}"; do wait "$p"; done
cat "$OUT"/keyframe_accuracy_tokens.log "$OUT"/keyframe_accuracy_pixels.log
