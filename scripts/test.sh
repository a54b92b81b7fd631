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
