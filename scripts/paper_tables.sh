#!/usr/bin/env bash
# The paper's three tables on ABM-Bench (issue 25): ONE multi-task policy per method over the 8 paper tasks,
# trained on the same seen demonstrations with the same recipe, views and model size, then
#   Table 1  every model on the 8 tasks, seen and unseen objects
#   Table 2  the Table-1 models on the two compositional tasks (never trained on)
#   Table 3  the mask-fusion ablations (stack, concat-rerendered, concat-full) beside abm (center-pixel)
# Runs (one folder each under OUT):
#   abm_oracle   abm, target mask from the simulator's segmentation (upper bound; needs no CLIP)
#   rvt_clip     rvt, instruction through the benchmark CLIP's text encoder (the paper's RVT had CLIP text)
#   abm_clip     abm, the benchmark CLIP's Object Mask Field with the package's default grounding configuration;
#                its skill text ("put X in the wine rack") through the benchmark CLIP's text encoder
#   abm_clip_hash  the same mask field, skill text through the hash encoder (a distinct code per text; the
#                benchmark CLIP's text tower was trained on object captions only)
#   ifd_clip     ifd, benchmark-CLIP point features and text
#   stack, concat-rerendered, concat-full   the ablations, grounded and worded like abm_clip_hash (Table 3's
#                center-pixel row)
# Every finished model is exported (bfloat16) into the model zoo (ZOO, default models/) with its index, and
# evaluated FROM THE ZOO FILE, so `abm eval --run models/NAME.pt ...` reproduces its row on a fresh clone.
#
# Usage: bash scripts/paper_tables.sh [OUT]        (default OUT=runs/paper)
# Knobs (environment): RUNS (all eight, in training order), CLIP (models/benchmark-clip), DEMOS (20 per task),
#   STEPS (5000), EVAL_EPISODES (25), REPEATS (2), EVAL_WORKERS (2), MAX_STEPS (8), DIAGNOSE_EPISODES (5),
#   COMPILE (0; 1 adds --compile), STAGES ("data ground train eval diagnose zoo report"), README (README.md; "" =
#   skip), ZOO (models), THREADS (per trainer: 1 for a pair, 2 for one left alone).
# Resumable at every stage: demonstrations are kept, grounding caches are filled once, trainings continue
# from their last checkpoint (--resume), evaluations skip finished episodes, finished exports are kept.
# Across machines: at the end of every pair, unfinished trainings leave their latest checkpoint and log in
# ZOO/carry/NAME/ (commit it); a rerun on a fresh clone continues from there. Before a session ends while
# trainings or evaluations still run, `STAGES=carry bash scripts/paper_tables.sh OUT` copies their latest
# checkpoints and the outcomes of unfinished evaluations (ZOO/carry/eval/NAME/SPLIT) there.
# Cost on a 2-core CPU: data ~20 min, two trainings at a time with one thread each (~2 h per pair at
# 5000 steps), evaluation ~4 s per rollout per worker (a Table-1 row: 850 rollouts).
set -euo pipefail
cd "$(dirname "$0")/.."
[ -x .venv/bin/abm ] || bash scripts/bootstrap.sh
export PATH="$PWD/.venv/bin:$PATH" MUJOCO_GL="${MUJOCO_GL:-egl}" OMP_WAIT_POLICY="${OMP_WAIT_POLICY:-PASSIVE}"

OUT="${1:-runs/paper}"
ZOO="${ZOO:-models}"
CLIP="${CLIP:-$ZOO/benchmark-clip}"
DATA="${DATA:-$OUT/data}"
TASKS="close_jar insert_peg pick_block place_food place_wine put_in_shelf take_off_pan water_plants"
COMPOSITIONAL="place_block_in_plate pick_food_to_target"
RUNS="${RUNS:-abm_oracle rvt_clip abm_clip ifd_clip abm_clip_hash stack concat-rerendered concat-full}"
TABLE1="abm_oracle rvt_clip abm_clip ifd_clip abm_clip_hash"
DEMOS="${DEMOS:-20}"
STEPS="${STEPS:-5000}"
EVAL_EPISODES="${EVAL_EPISODES:-25}"
REPEATS="${REPEATS:-2}"
EVAL_WORKERS="${EVAL_WORKERS:-2}"
MAX_STEPS="${MAX_STEPS:-8}"
COMPILE="${COMPILE:-0}"
STAGES="${STAGES:-data ground train eval diagnose zoo report}"
README="${README-README.md}"
mkdir -p "$OUT" "$ZOO"
# on a fresh clone: the finished evaluations, diagnoses and zoo eval come back from docs/results/paper_tables/
python benchmarks/paper_tables_report.py "$OUT" --restore-only
TIMES="$OUT/times.txt"
stamp() { echo "$1 $(date +%s)" >> "$TIMES"; }
stage() { [[ " $STAGES " == *" $1 "* ]]; }
needs_clip() { [ "$1" != abm_oracle ]; }
have_clip() {
  [ -f "$CLIP/config.json" ] && return 0
  echo "no benchmark CLIP in $CLIP: train it (abm clip train --out $CLIP) or set CLIP=DIR" >&2
  return 1
}

# ----------------------------------------------------------------------------------------------- data
if stage data; then
  stamp data_start
  abm data generate --task "${TASKS// /,}" --split seen --episodes "$DEMOS" --out "$DATA" --workers 2
  stamp data_end
fi

# ------------------------------------------------------------------------------ the explicit grounding step
if stage ground && [[ "$RUNS" != abm_oracle ]] && have_clip; then
  stamp ground_start
  # shellcheck disable=SC2086
  abm data ground --data "$DATA" --cache "$OUT/cache_masks" --clip-model "$CLIP" --tasks $TASKS
  if [[ " $RUNS " == *" ifd_clip "* ]]; then
    # shellcheck disable=SC2086
    abm data ground --data "$DATA" --cache "$OUT/cache_features" --clip-model "$CLIP" --features --tasks $TASKS
  fi
  stamp ground_end
fi

# ------------------------------------------------------------------------------------------- training
train_one() {  # run name, threads -> one multi-task training (resumes), then its zoo export
  local name="$1" threads="$2" extra=() flags=()
  case "$name" in
    abm_oracle) extra=(--method abm --grounder oracle) ;;
    rvt_clip) extra=(--method rvt --language clip --clip-model "$CLIP") ;;
    abm_clip) extra=(--method abm --grounder clip --clip-model "$CLIP" --cache-dir "$OUT/cache_masks") ;;
    ifd_clip) extra=(--method ifd --grounder clip --clip-model "$CLIP" --cache-dir "$OUT/cache_features") ;;
    abm_clip_hash) extra=(--method abm --grounder clip --clip-model "$CLIP" --cache-dir "$OUT/cache_masks"
                          --language hash) ;;
    stack|concat-rerendered|concat-full)  # compared with abm_clip_hash (the same mask field and language)
      extra=(--method "$name" --grounder clip --clip-model "$CLIP" --cache-dir "$OUT/cache_masks"
             --language hash) ;;
    *) echo "unknown run $name" >&2; return 1 ;;
  esac
  [ "$COMPILE" = 1 ] && flags+=(--compile)
  if [ -f "$ZOO/$name.pt" ]; then return 0; fi  # finished and exported earlier
  local carry="$ZOO/carry/$name"
  if [ -d "$carry" ] && [ ! -d "$OUT/$name/checkpoints" ]; then  # a fresh clone: continue the committed state
    mkdir -p "$OUT/$name/checkpoints"
    cp "$carry"/step_*.pt "$OUT/$name/checkpoints/"
    [ -f "$carry/log.csv" ] && cp "$carry/log.csv" "$OUT/$name/"
  fi
  # shellcheck disable=SC2086
  OMP_NUM_THREADS="$threads" MKL_NUM_THREADS="$threads" abm train --config paper_tables "${extra[@]}" \
    "${flags[@]}" --data "$DATA" --tasks $TASKS --steps "$STEPS" --no-progress --out "$OUT/$name" --resume \
    > "$OUT/train_$name.log" 2>&1 || return 1
  abm export --run "$OUT/$name" --out "$ZOO/$name.pt" --dtype bfloat16
  rm -rf "$carry"
  python benchmarks/paper_tables_report.py "$OUT" --zoo "$ZOO" --index-only
}

carry_unfinished() {  # keep what a continuation on another machine needs (call before the session ends)
  local name latest folder
  for folder in "$OUT"/eval/*/*/; do  # unfinished evaluations: their outcomes so far (small JSON lines)
    [ -f "$folder/outcomes.jsonl" ] && [ ! -f "$folder/results.json" ] || continue
    name="${folder#"$OUT"/eval/}"; name="${name%/}"
    rm -rf "$ZOO/carry/eval/$name" && mkdir -p "$ZOO/carry/eval/$name"
    cp "$folder"/outcomes.jsonl "$ZOO/carry/eval/$name/"
    [ -f "$folder/evaluation.json" ] && cp "$folder/evaluation.json" "$ZOO/carry/eval/$name/"
  done
  for name in $RUNS; do
    [ -f "$ZOO/$name.pt" ] && continue
    latest=$(ls "$OUT/$name/checkpoints"/step_*.pt 2>/dev/null | sort | tail -n 1) || true
    [ -n "$latest" ] || continue
    rm -rf "$ZOO/carry/$name" && mkdir -p "$ZOO/carry/$name"
    cp "$latest" "$ZOO/carry/$name/"
    [ -f "$OUT/$name/log.csv" ] && cp "$OUT/$name/log.csv" "$ZOO/carry/$name/"
  done
}

if stage carry; then  # STAGES=carry: only copy the running trainings' latest state into ZOO/carry (then commit it)
  carry_unfinished
fi

if stage train; then
  stamp train_start
  trap 'carry_unfinished; kill $(jobs -p) 2>/dev/null || true' INT TERM
  todo=()
  for name in $RUNS; do
    if needs_clip "$name" && ! have_clip; then continue; fi
    todo+=("$name")
  done
  set -- "${todo[@]}"
  while [ $# -gt 0 ]; do  # two trainers at a time, one thread each (two threads for one left alone)
    pids=()
    threads=1; [ -n "${2:-}" ] || threads=2
    threads="${THREADS:-$threads}"
    for name in "$1" "${2:-}"; do
      [ -n "$name" ] || continue
      train_one "$name" "$threads" &
      pids+=($!)
    done
    for p in "${pids[@]}"; do wait "$p" || { carry_unfinished; echo "training failed: see $OUT/train_*.log" >&2; exit 1; }; done
    shift; [ $# -gt 0 ] && shift
  done
  trap - INT TERM
  stamp train_end
fi

# ----------------------------------------------------------------------------------------- evaluation
restore_eval() {  # eval folder -> on a fresh clone, continue from the outcomes carried in ZOO/carry/eval
  local carried="$ZOO/carry/eval/${1#"$OUT"/eval/}"
  if [ -d "$carried" ] && [ ! -f "$1/outcomes.jsonl" ]; then mkdir -p "$1" && cp "$carried"/* "$1/"; fi
}

if stage eval; then
  stamp eval_start
  trap 'carry_unfinished; kill $(jobs -p) 2>/dev/null || true' INT TERM
  for name in $RUNS; do
    [ -f "$ZOO/$name.pt" ] || { echo "skip evaluating $name: $ZOO/$name.pt is not trained yet" >&2; continue; }
    for s in seen unseen; do
      [ -f "$OUT/eval/$name/$s/results.json" ] && continue  # finished (here, or restored from the kept copy)
      restore_eval "$OUT/eval/$name/$s"
      # shellcheck disable=SC2086
      abm eval --run "$ZOO/$name.pt" --tasks $TASKS --split "$s" --episodes "$EVAL_EPISODES" --repeats "$REPEATS" \
        --workers "$EVAL_WORKERS" --max-steps "$MAX_STEPS" --out "$OUT/eval/$name/$s"
    done
    if [[ " $TABLE1 " == *" $name "* ]] && [ ! -f "$OUT/eval/$name/compositional/results.json" ]; then
      restore_eval "$OUT/eval/$name/compositional"
      # shellcheck disable=SC2086
      abm eval --run "$ZOO/$name.pt" --tasks $COMPOSITIONAL --split compositional --episodes "$EVAL_EPISODES" \
        --repeats "$REPEATS" --workers "$EVAL_WORKERS" --max-steps "$MAX_STEPS" --out "$OUT/eval/$name/compositional"
    fi
    rm -rf "${ZOO:?}/carry/eval/$name"  # this run's evaluations are finished (others may still run elsewhere)
  done
  trap - INT TERM
  stamp eval_end
fi

# ---------------------------------------- diagnosis: keyframe accuracy on expert scenes (teacher-forced)
if stage diagnose; then  # per keyframe kind: position and rotation error of each zoo model (~3 min per model),
  # and of each CLIP-grounded mask model with the oracle mask
  mkdir -p "$OUT/keyframe_accuracy"
  for name in $RUNS; do
    [ -f "$ZOO/$name.pt" ] && [ ! -f "$OUT/keyframe_accuracy/$name.json" ] || continue
    # shellcheck disable=SC2086
    python benchmarks/keyframe_accuracy.py --run "$ZOO/$name.pt" --tasks $TASKS --splits seen unseen \
      --episodes "${DIAGNOSE_EPISODES:-5}" --out "$OUT/keyframe_accuracy/$name.json" > "$OUT/keyframe_accuracy/$name.log"
  done
  for name in $RUNS; do  # a CLIP-grounded mask run fed the oracle mask: what stays wrong is the policy's, not the mask's
    case "$name" in abm_oracle|rvt_clip|ifd_clip) continue ;; esac
    [ -f "$ZOO/$name.pt" ] && [ ! -f "$OUT/keyframe_accuracy/$name@oracle.json" ] || continue
    # shellcheck disable=SC2086
    python benchmarks/keyframe_accuracy.py --run "$ZOO/$name.pt" --tasks $TASKS --splits seen unseen \
      --episodes "${DIAGNOSE_EPISODES:-5}" --grounder oracle --out "$OUT/keyframe_accuracy/$name@oracle.json" \
      > "$OUT/keyframe_accuracy/$name@oracle.log"
  done
fi

# ------------------------------------------------- what a new user runs first: abm zoo eval, timed
if stage zoo && [ -f "$ZOO/abm_clip.pt" ] && [ -f "$ZOO/rvt_clip.pt" ] && [ ! -f "$OUT/zoo_eval/seconds" ]; then
  started=$(date +%s)
  abm zoo eval --zoo "$ZOO" --out "$OUT/zoo_eval"
  echo $(( $(date +%s) - started )) > "$OUT/zoo_eval/seconds"
fi

if stage report; then
  python benchmarks/paper_tables_report.py "$OUT" --zoo "$ZOO" --clip "$CLIP" --readme "$README" --command "bash $0 $*"
fi
