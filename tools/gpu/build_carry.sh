#!/bin/bash
# Build what a lent GPU machine (Python 3.12, its own torch and numpy, no network) needs to run this
# package: .gpu/site.tar.xz (SAPIEN, ManiSkill with the Panda's model only, their pure-Python needs),
# .gpu/oidn.tar.xz (SAPIEN's denoiser and sensor modules, which pysapien links), a few wheels, and
# .gl/ (the Vulkan and GL loaders). Run from the repository root on a machine that reaches PyPI and
# Debian; then, on the GPU machine, `source tools/gpu/env.sh` with `.gl` and `.gpu` carried.
# ManiSkill's GPU simulation also needs PhysX's GPU library, which SAPIEN downloads from GitHub:
# put ~/.sapien/physx/<version>/libPhysXGpu_64.so into .gpu/physx/ if you have it (env.sh installs it).
set -euo pipefail
ROOT=$(pwd)
PY=${PY:-.venv/bin/python}
SP=$($PY -c "import mani_skill, os; print(os.path.dirname(os.path.dirname(mani_skill.__file__)))")
grep -qx '/.gpu/' .git/info/exclude 2>/dev/null || printf '/.gpu/\n/.gl/\n' >> .git/info/exclude
WHL=$(mktemp -d); STAGE=$(mktemp -d); mkdir -p .gpu "$STAGE/site" "$STAGE/extra"
PLAT="--python-version 3.12 --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 --platform any"
get() { $PY -m pip download -q --no-deps --only-binary=:all: $PLAT -d "$1" "${@:2}"; }
# compiled and pure-Python packages the GPU image lacks (its torch, numpy, scipy, cv2, h5py stay)
get "$WHL" sapien==3.0.3 transforms3d trimesh gymnasium==1.4.0 farama-notifications dacite tyro \
  docstring-parser shtab typeguard pyperclip importlib_resources coacd==1.0.14 arm_pytorch_utilities \
  GitPython gitdb smmap defusedxml
(cd "$STAGE/site" && for w in "$WHL"/*.whl; do unzip -q -o "$w"; done)
# what SAPIEN's import needs but is large: split off (denoiser weights) or dropped (headers, patterns)
mv "$STAGE/site/sapien/oidn_library" "$STAGE/site/sapien/sensor" "$STAGE/extra/"
rm -rf "$STAGE/site/sapien/include" "$STAGE/extra/oidn_library/"*device_cuda* \
  "$STAGE/extra/sensor/assets/patterns/d415.png"
mkdir -p "$STAGE/extra/sapien" && mv "$STAGE/extra/oidn_library" "$STAGE/extra/sensor" "$STAGE/extra/sapien/"
# ManiSkill as installed here (pure Python), with only the Panda's robot model
tar -C "$SP" -cf - --exclude=__pycache__ --exclude='mani_skill/assets/environment_maps' \
  --exclude='mani_skill/assets/maniskill2-scene-2.glb' --exclude='mani_skill/assets/robots' \
  --exclude='*.hdr' mani_skill mani_skill-3.0.1.dist-info | tar -C "$STAGE/site" -xf -
mkdir -p "$STAGE/site/mani_skill/assets/robots"
tar -C "$SP/mani_skill/assets/robots" -cf - --exclude=realsense2_description \
  --exclude=sciurus17_description panda | tar -C "$STAGE/site/mani_skill/assets/robots" -xf -
XZ_OPT="-9 -T2" tar -cJf .gpu/site.tar.xz -C "$STAGE" site
XZ_OPT="-9 -T2" tar -cJf .gpu/oidn.tar.xz -C "$STAGE/extra" sapien
# imported by mani_skill's controllers and IPython hooks, and by the tests (shapely)
rm -f .gpu/*.whl
get .gpu pytorch-kinematics==0.7.6 pytorch-seed==0.2.0 ipython==9.18.1 ipython_pygments_lexers==1.1.1 \
  jedi==0.20.1 parso==0.8.7 matplotlib-inline==0.2.2 pexpect==4.9.0 prompt_toolkit==3.0.53 \
  ptyprocess==0.7.0 pure_eval==0.2.4 stack-data==0.6.3 traitlets==5.16.1 wcwidth==0.9.4 \
  asttokens==3.0.2 executing==2.3.0 truststore==0.10.5 shapely==2.0.7
mkdir -p .gl /tmp/amd64/partial
o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64'
apt-get $o update -qq && (cd .gl && apt-get $o download -qq libvulkan1 libegl1 libglvnd0 libopengl0 \
  libgl1 libglx0 libgles2)
rm -rf "$WHL" "$STAGE"
du -sh .gpu .gl
