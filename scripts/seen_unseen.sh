#!/usr/bin/env bash
# The seen/unseen experiment behind the README's policy table: abm and rvt trained on the same seen
# demonstrations, evaluated on seen and unseen objects, table written into README.md.
#
# Usage: bash scripts/seen_unseen.sh [OUT]        (default OUT=runs/seen_unseen)
# Knobs (environment): TASKS ("pick_block place_food"), DEMOS (20 per task), STEPS (4000),
#   EVAL_EPISODES (25), REPEATS (1), EVAL_WORKERS (2), KEYFRAME_EPISODES (10), README (README.md; "" = skip).
# Every stage resumes: existing demonstrations are kept, training continues from its last checkpoint
# (--resume) and evaluation skips finished episodes. 2-core CPU: ~70 min of training (both methods side
# by side, one thread each) and ~25 min of evaluation.
set -euo pipefail
cd "$(dirname "$0")/.."
[ -x .venv/bin/abm ] || bash scripts/bootstrap.sh
export PATH="$PWD/.venv/bin:$PATH" MUJOCO_GL="${MUJOCO_GL:-egl}"

OUT="${1:-runs/seen_unseen}"
TASKS="${TASKS:-pick_block place_food}"
DEMOS="${DEMOS:-20}"
STEPS="${STEPS:-4000}"
EVAL_EPISODES="${EVAL_EPISODES:-25}"
REPEATS="${REPEATS:-1}"
EVAL_WORKERS="${EVAL_WORKERS:-2}"
KEYFRAME_EPISODES="${KEYFRAME_EPISODES:-10}"
README="${README-README.md}"
mkdir -p "$OUT"
TIMES="$OUT/times.txt"
stamp() { echo "$1 $(date +%s)" >> "$TIMES"; }

stamp data_start
abm data generate --task "${TASKS// /,}" --split seen --episodes "$DEMOS" --out "$OUT/data" --workers 2
stamp data_end

stamp train_start
# the two trainers run in the background: stop them with the script (Ctrl-C, an error, the end)
trap 'kill $(jobs -p) 2>/dev/null || true' INT TERM EXIT
pids=()
for m in abm rvt; do
  # the recipe (batch 8, AdamW 1e-3, 50 warm-up steps, 64-pixel views, ...) is configs/seen_unseen.yaml
  OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 abm train --config configs/seen_unseen.yaml --method "$m" --data "$OUT/data" \
    --steps "$STEPS" --no-progress --out "$OUT/$m" --resume > "$OUT/train_$m.log" 2>&1 &
  pids+=($!)
done
rc=0
for p in "${pids[@]}"; do wait "$p" || rc=1; done
if [ "$rc" != 0 ]; then echo "training failed: see $OUT/train_abm.log and $OUT/train_rvt.log" >&2; exit 1; fi
stamp train_end

stamp eval_start
for s in seen unseen; do
  # shellcheck disable=SC2086
  abm eval --run "$OUT/abm" --run "$OUT/rvt" --tasks $TASKS --split "$s" --episodes "$EVAL_EPISODES" \
    --repeats "$REPEATS" --workers "$EVAL_WORKERS" --max-steps 8 --out "$OUT/eval_$s"
done
stamp eval_end

stamp keyframes_start
steps=()
for ((k = 1000; k < STEPS; k += 1000)); do steps+=("$k"); done
# shellcheck disable=SC2086
python benchmarks/keyframe_accuracy.py --run "$OUT/abm" --run "$OUT/rvt" --tasks $TASKS \
  --episodes "$KEYFRAME_EPISODES" --steps "${steps[@]}" --out "$OUT/keyframes.json" --kinds approach grasp move place
stamp keyframes_end

python benchmarks/seen_unseen_report.py "$OUT" --readme "$README" --command "$0 $*"
