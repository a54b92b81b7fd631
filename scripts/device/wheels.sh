#!/usr/bin/env bash
# Download the wheels abm needs on the GPU machine (Python 3.12 image with torch, transformers, h5py,
# matplotlib and tqdm, but no internet), into ./wheels, to carry there with the device tool
# (carry: ["wheels"], 64 MiB at most). Run here, where the package registry is reachable.
set -euo pipefail
cd "$(dirname "$0")/../.."
mkdir -p wheels
python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --platform manylinux2014_x86_64 \
  --platform manylinux_2_17_x86_64 --platform manylinux_2_28_x86_64 -d wheels \
  torch-optimizer pytorch-ranger pyyaml scipy
du -sh wheels
