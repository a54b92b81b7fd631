#!/usr/bin/env bash
# Set up abm on a fresh machine: a virtual environment in .venv with the CPU build of torch
# installed first (so nothing pulls CUDA wheels), then abm with all extras.
# Idempotent: re-running only installs what is missing. Usage: bash scripts/bootstrap.sh
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3}
VENV=${ABM_VENV:-.venv}
TORCH_SPEC=${ABM_TORCH_SPEC:-torch==2.13.0}

if [ ! -x "$VENV/bin/python" ]; then
  echo "[bootstrap] creating $VENV"
  "$PYTHON" -m venv "$VENV"
fi
PIP="$VENV/bin/python -m pip --disable-pip-version-check -q"

if ! "$VENV/bin/python" -c "import torch" 2>/dev/null; then
  echo "[bootstrap] installing $TORCH_SPEC (first, so no other package pulls a CUDA build)"
  $PIP install "$TORCH_SPEC"
fi

echo "[bootstrap] installing abm and its dependencies"
$PIP install -e ".[all]"
"$VENV/bin/python" -c "import abm, torch; print(f'[bootstrap] abm {abm.__version__} with torch {torch.__version__} ready in $VENV')"
