#!/usr/bin/env bash
# The two-target experiment: abm (grounding the active sub-goal: X, then Y once the gripper holds X) trained
# on seen put_in_container demonstrations with the quickstart recipe, evaluated on seen, unseen and
# compositional scenes; writes docs/results/put_in_container.md from the evaluations' own tables.
#
# Usage: bash scripts/put_in_container.sh [OUT]      (default OUT=runs/container)
# Knobs (environment): DEMOS (20), STEPS (1400), EVAL_EPISODES (10). Every stage resumes.
# 2-core CPU, one thread: ~2 min of data, ~22 min of training, ~15 min of evaluation.
set -euo pipefail
cd "$(dirname "$0")/.."
[ -x .venv/bin/abm ] || bash scripts/bootstrap.sh
export PATH="$PWD/.venv/bin:$PATH" MUJOCO_GL="${MUJOCO_GL:-egl}" OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
OUT="${1:-runs/container}"
DEMOS="${DEMOS:-20}"
STEPS="${STEPS:-1400}"
EVAL_EPISODES="${EVAL_EPISODES:-10}"
REPORT="${REPORT:-docs/results/put_in_container.md}"

abm data generate --task put_in_container --split seen --episodes "$DEMOS" --out "$OUT/data" --workers 1
# the quickstart recipe: batch 8, AdamW 1e-3, 48-pixel views over a 0.6 m cube, checkpoints every 350 steps
abm train --config configs/quickstart.yaml --method abm --data "$OUT/data" --steps "$STEPS" --no-progress \
  --out "$OUT/abm" --resume
for s in seen unseen compositional; do
  abm eval --run "$OUT/abm" --tasks put_in_container --split "$s" --episodes "$EVAL_EPISODES" --max-steps 8 \
    --workers 1 --gifs 1 --out "$OUT/eval_$s"
done

{
  echo "# put_in_container: two targets per instruction"
  echo
  echo "Written by \`bash scripts/put_in_container.sh\` on $(python -c 'from abm.machine import describe_machine; print(describe_machine())')."
  echo "abm (active sub-goal mask, oracle grounder) trained on $DEMOS seen demonstrations, $STEPS steps of the quickstart"
  echo "recipe (48² views, 0.6 m cube, AdamW 1e-3, batch 8); $EVAL_EPISODES seeded evaluation episodes x 5 repeats ($((EVAL_EPISODES * 5))"
  echo "scenes) per split, at most 8 keyframes; mean ± std over the repeats. Seen: objects and containers of the training lists, in pairs seen in training; unseen: new"
  echo "objects in new containers; compositional: seen objects in seen containers, in pairs never demonstrated."
  for s in seen unseen compositional; do
    echo
    echo "## $s"
    echo
    sed '/report.html/d' "$OUT/eval_$s/results.md"
  done
} > "$REPORT"
echo "wrote $REPORT"
