#!/usr/bin/env bash
# The CLIP-grounder experiment (issue 17, part 3): the method and its baselines with a *learned* grounder
# (the benchmark CLIP of `abm clip train`, trained on renders of every catalog object, never on
# demonstrations) beside the same methods with the oracle grounder / weight-free hash language:
#   abm_oracle  abm, target mask from the simulator's segmentation (upper bound)
#   abm_clip    abm, target mask from the CLIP Object Mask Field
#   rvt_hash    rvt, instruction through the weight-free hash encoder
#   rvt_clip    rvt, instruction through CLIP's text encoder
#   ifd_clip    ifd, per-point CLIP features (no mask, no target name beyond the language tokens)
# plus abm_oracle evaluated with CLIP masks (trained on oracle masks, grounded by CLIP only at test time).
# All five train on the same seen demonstrations with the quickstart recipe (48² views over a 0.6 m cube,
# 1400 steps of AdamW 1e-3, batch 8) and are evaluated on the same seeded seen and unseen scenes; CLIP
# methods ground with CLIP at evaluation as well. Writes docs/results/clip_grounder.md through
# benchmarks/clip_grounder_report.py.
#
# Usage: bash scripts/clip_grounder.sh [OUT]       (default OUT=runs/clip_grounder)
# Knobs (environment): CLIP (models/benchmark-clip, the committed benchmark CLIP, or any `abm clip train` folder),
#   DATA (OUT/data; generated with DEMOS=20 seen demonstrations of each of TASKS when missing), TASKS ("pick_block place_food"),
#   STEPS (1400), EVAL_EPISODES (10), REPEATS (3), METHODS (all five), REPORT (docs/results/clip_grounder.md).
# Every stage resumes. 2-core CPU: ~1 min of CLIP caching, ~75 min of training (two runs side by side, one
# thread each; 25 min per pair), ~25 min of evaluation (720 rollouts, ~4 s each per worker).
set -euo pipefail
cd "$(dirname "$0")/.."
[ -x .venv/bin/abm ] || bash scripts/bootstrap.sh
export PATH="$PWD/.venv/bin:$PATH" MUJOCO_GL="${MUJOCO_GL:-egl}"

OUT="${1:-runs/clip_grounder}"
CLIP="${CLIP:-models/benchmark-clip}"
DATA="${DATA:-$OUT/data}"
TASKS="${TASKS:-pick_block place_food}"
DEMOS="${DEMOS:-20}"
STEPS="${STEPS:-1400}"
EVAL_EPISODES="${EVAL_EPISODES:-10}"
REPEATS="${REPEATS:-3}"
METHODS="${METHODS:-abm_oracle abm_clip rvt_hash rvt_clip ifd_clip}"
REPORT="${REPORT:-docs/results/clip_grounder.md}"
if [ ! -f "$CLIP/config.json" ]; then
  echo "no CLIP model in $CLIP: train the benchmark CLIP first (abm clip train --out $CLIP) or set CLIP=DIR" >&2
  exit 1
fi
mkdir -p "$OUT"
TIMES="$OUT/times.txt"
stamp() { echo "$1 $(date +%s)" >> "$TIMES"; }
# the workspace cube of the quickstart recipe (configs/quickstart.yaml), for the grounding cache
CUBE=(--workspace-center 0.5 0.0 0.15 --workspace-size 0.6)

stamp data_start
for t in $TASKS; do
  abm data generate --task "$t" --split seen --episodes "$DEMOS" --out "$DATA" --workers 2
done
stamp data_end

stamp ground_start
# the explicit grounding step: CLIP mask fields (abm) and CLIP point features (ifd) of every keyframe, once
# shellcheck disable=SC2086
abm data ground --data "$DATA" --cache "$OUT/cache_masks" --clip-model "$CLIP" --tasks $TASKS "${CUBE[@]}"
# shellcheck disable=SC2086
abm data ground --data "$DATA" --cache "$OUT/cache_features" --clip-model "$CLIP" --features --tasks $TASKS "${CUBE[@]}"
stamp ground_end

train_one() {  # run folder name, threads -> abm train with that method's grounder / language
  local name="$1" threads="$2" extra=()
  case "$name" in
    abm_oracle) extra=(--method abm --grounder oracle) ;;
    abm_clip) extra=(--method abm --grounder clip --clip-model "$CLIP" --cache-dir "$OUT/cache_masks") ;;
    rvt_hash) extra=(--method rvt --language hash) ;;
    rvt_clip) extra=(--method rvt --language clip --clip-model "$CLIP") ;;
    ifd_clip) extra=(--method ifd --grounder clip --clip-model "$CLIP" --cache-dir "$OUT/cache_features") ;;
    *) echo "unknown method $name" >&2; return 1 ;;
  esac
  # shellcheck disable=SC2086
  # exec: the background job is the trainer itself, so the trap below stops it
  OMP_NUM_THREADS="$threads" MKL_NUM_THREADS="$threads" exec abm train "${extra[@]}" --data "$DATA" --tasks $TASKS --steps "$STEPS" \
    --config configs/quickstart.yaml --no-progress \
    --out "$OUT/$name" --resume > "$OUT/train_$name.log" 2>&1
}

stamp train_start
trap 'kill $(jobs -p) 2>/dev/null || true' INT TERM EXIT
# two trainers at a time, one thread each (two threads for one left alone)
# shellcheck disable=SC2086
set -- $METHODS
while [ $# -gt 0 ]; do
  pids=()
  threads=1; [ -n "${2:-}" ] || threads=2
  for name in "$1" "${2:-}"; do
    [ -n "$name" ] || continue
    train_one "$name" "$threads" &
    pids+=($!)
  done
  for p in "${pids[@]}"; do wait "$p" || { echo "training failed: see $OUT/train_*.log" >&2; exit 1; }; done
  shift; [ $# -gt 0 ] && shift
done
stamp train_end

stamp eval_start
runs=()
for name in $METHODS; do runs+=(--run "$OUT/$name"); done
for s in seen unseen; do
  # shellcheck disable=SC2086
  abm eval "${runs[@]}" --tasks $TASKS --split "$s" --episodes "$EVAL_EPISODES" --repeats "$REPEATS" \
    --workers 2 --max-steps 8 --gifs 1 --out "$OUT/eval_$s"
  if [[ " $METHODS " == *" abm_oracle "* ]]; then  # the oracle-trained policy, grounded by CLIP at test time
    # shellcheck disable=SC2086
    abm eval --run "$OUT/abm_oracle" --grounder clip --clip-model "$CLIP" --tasks $TASKS --split "$s" \
      --episodes "$EVAL_EPISODES" --repeats "$REPEATS" --workers 2 --max-steps 8 --out "$OUT/eval_${s}_oracle_trained_clip"
  fi
done
stamp eval_end

python benchmarks/clip_grounder_report.py "$OUT" --clip "$CLIP" --report "$REPORT" --command "bash $0 ${OUT}"
