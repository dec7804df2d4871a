#!/usr/bin/env bash
# Prepare the backbone's GPU recipe for a lent device machine (the `device` tool of this workplace:
# Python 3.12 with PyTorch+CUDA, no network, at most 64 MiB of working tree a call). Builds the
# ignored folder .gpu/ with what that machine lacks, trimmed to fit: recon's pure dependencies for
# cp312 (kornia, roma, trimesh, tabulate, moderngl, glcontext, anny's code, warp's Python without
# its 350 MB of binaries: recon never starts warp's runtime), a stand-in for kornia_rs (kornia
# imports it for image I/O, which recon never calls), the anny float32 export, and a launcher.
# Then, per device call (tracked weights that the recipe does not read must be moved out first:
# the tree travels whole; docs/backbone.md lists them):
#   run(command="bash .gpu/run.sh --minutes 13 --run-minutes 6.5", carry=[".gpu", ".gl"])
set -euo pipefail
cd "$(dirname "$0")/.."
mkdir -p .git/info .gpu/cache
grep -qx "/.gpu/" .git/info/exclude 2>/dev/null || echo "/.gpu/" >> .git/info/exclude
grep -qx "/.gl/" .git/info/exclude 2>/dev/null || echo "/.gl/" >> .git/info/exclude
rm -rf .gpu/site
python3 -m pip install -q --no-deps --no-compile --only-binary=:all: --python-version 3.12 --implementation cp \
  --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
  --platform manylinux_2_34_x86_64 --target .gpu/site \
  kornia==0.9.0 moderngl==5.13.0 glcontext==3.1.0 roma==1.8.0 tabulate==0.10.0 trimesh==5.2.0 anny==0.6.2 \
  warp-lang==1.19.0
(cd .gpu/site && rm -rf warp/bin warp/tests warp/examples warp/native warp/fem warp/__init__.pyi moderngl-stubs \
  anny/examples anny/data/{mpfb2,soma,cached,faceunits01,keypoints,topology} \
  anny/data/template_mesh_internal_cavities.pth && find . -name RECORD -delete)
mkdir -p .gpu/site/kornia_rs
printf '%s\n' "# stand-in: kornia imports kornia_rs for image I/O, which recon never calls" "import types" \
  "io = types.SimpleNamespace()" > .gpu/site/kornia_rs/__init__.py
cp "$(.venv/bin/python -c 'from recon.body.anny_model import export_path; print(export_path())')" .gpu/cache/
# EGL through the machine's NVIDIA driver (the device README's recipe)
mkdir -p .gl /tmp/amd64/partial
o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64'
apt-get $o update -qq && (cd .gl && apt-get $o download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)
cat > .gpu/run.sh <<'RUN'
# on the device machine: `recon backbone recipe` with the carried dependencies; outputs to $OUT
set -o pipefail
for f in .gl/*.deb; do dpkg -x $f /; done; ldconfig
v=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json; [ -f $v ] && export __EGL_VENDOR_LIBRARY_FILENAMES=$v
export PYTHONPATH=$PWD/.gpu/site:$PWD RECON_CACHE_DIR=$PWD/.gpu/cache PYTHONUNBUFFERED=1 OMP_NUM_THREADS=1
python3 -m recon.cli backbone recipe --out runs/gpu-recipe "$@" 2>&1 | grep -v "step/s\]\|shard/s\]" | tee $OUT/log.txt
rc=$?
for f in recon/backbone/weights/hourglass_base.pt recon/backbone/weights/MODEL_CARD.md eval/results/backbone-gpu-recipe.json \
  eval/results/backbone-gpu-recipe.md runs/gpu-recipe/run/curve.json; do [ -f $f ] && cp $f $OUT/; done
exit $rc
RUN
du -sh .gpu .gl
