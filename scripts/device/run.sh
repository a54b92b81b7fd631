#!/usr/bin/env bash
# Run abm on the lent GPU machine (see docs/performance.md): installs the carried wheels without
# dependencies, uses the image's own torch, and writes results and logs under $OUT.
#
#   bash scripts/device/run.sh bench            # GPU benchmarks: renderer, policy step, mask field, training
#   bash scripts/device/run.sh test             # CUDA-vs-CPU agreement tests
#   bash scripts/device/run.sh train ARGS...    # abm train --device cuda ARGS; logs + bf16 policy in parts to $OUT
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=${OUT:-out/device}
mkdir -p "$OUT"
if compgen -G "wheels/*.whl" >/dev/null; then
  python -m pip install -q --no-deps --no-index wheels/*.whl
fi
export PYTHONPATH="$PWD/src${PYTHONPATH:+:$PYTHONPATH}"
python - <<'PY' | tee "$OUT/env.txt"
import torch
print("torch", torch.__version__, "cuda", torch.cuda.is_available(),
      torch.cuda.get_device_name() if torch.cuda.is_available() else "")
PY
run() {  # name, command...: stdout to $OUT/name.txt, stderr to $OUT/name.log; a failure does not stop the rest
  local name=$1; shift
  "$@" > "$OUT/$name.txt" 2> "$OUT/$name.log" || echo "$name failed (see $OUT/$name.log)"
}
case "${1:-bench}" in
  bench)
    run render_speed python benchmarks/render_speed.py --device cuda
    run policy_speed python benchmarks/policy_speed.py --devices cuda --presets small paper
    run grounding_speed python benchmarks/grounding_speed.py --device cuda --dtype float16
    run train_speed_paper python benchmarks/train_speed.py --device cuda --preset paper --batch 24 --steps 20
    ;;
  test)
    python -m pytest tests/test_cuda_agreement.py -q -p no:cacheprovider 2>&1 | tee "$OUT/cuda_agreement.txt"
    ;;
  train)
    # Train outside $OUT (training checkpoints hold the optimizer state and can exceed what comes back),
    # then bring back the logs and a bfloat16 inference checkpoint cut into 15 MiB parts. Here:
    #   cat policy_bf16.pt.part* > policy.pt && abm eval --run policy.pt ...
    shift
    RUN=${RUN:-runs/device_run}
    python -m abm.cli train --device cuda "$@" --out "$RUN" 2>&1 | tee "$OUT/train.log"
    cp "$RUN"/*.json "$RUN"/*.csv "$OUT"/ 2>/dev/null || true
    python -m abm.cli export --run "$RUN" --out "$RUN/policy_bf16.pt" --dtype bfloat16
    split -b 15M -d -a 3 "$RUN/policy_bf16.pt" "$OUT/policy_bf16.pt.part"
    ;;
  *)
    echo "usage: bash scripts/device/run.sh bench|test|train [ARGS]" >&2; exit 2
    ;;
esac
