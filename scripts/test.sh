#!/usr/bin/env bash
# Set up (if needed) and run the whole test suite: lint, type check, then pytest. Usage: bash scripts/test.sh [pytest args]
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh  # also installs Chromium for the viewer's browser test (skipped when none is found)
.venv/bin/ruff check src tests benchmarks
.venv/bin/mypy  # files and strictness: [tool.mypy] in pyproject.toml
.venv/bin/python -m pytest "$@"
