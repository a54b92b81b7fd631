#!/usr/bin/env bash
# Set up (if needed) and run the whole test suite: lint, type check, then pytest in ABM_TEST_WORKERS processes
# (default 2, pytest-xdist; a test file stays in one process, so its module fixtures are built once; 0 = in this
# process). Usage: bash scripts/test.sh [pytest args]
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh  # also installs Chromium for the viewer's browser test (skipped when none is found)
.venv/bin/ruff check src tests benchmarks
.venv/bin/mypy  # files and strictness: [tool.mypy] in pyproject.toml
.venv/bin/python -m pytest -n "${ABM_TEST_WORKERS:-2}" --dist loadfile "$@"
# The tests that compare stored numeric outputs of torch code, again with the AVX-512 kernels switched off (ATen,
# oneDNN and MKL use AVX2 at most, as on an x86-64 CPU without AVX-512), so a difference between CPUs shows here
# (~20 CPU-seconds; docs/reliability.md). The scene sampler's saved outputs (test_task_sampling_golden.py) are
# numpy and MuJoCo only, which these switches do not touch.
if [ "$(uname -m)" = x86_64 ]; then
  ATEN_CPU_CAPABILITY=avx2 ONEDNN_MAX_CPU_ISA=AVX2 MKL_ENABLE_INSTRUCTIONS=AVX2 .venv/bin/python -m pytest -p no:xdist \
    tests/test_policy_golden.py "tests/test_old_checkpoints.py::test_old_checkpoint_loads_typed_and_predicts_the_same"
fi
