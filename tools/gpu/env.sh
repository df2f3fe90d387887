# Source on a lent GPU machine (with .gl and .gpu carried; see build_carry.sh): loaders, packages.
for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
[ -d /tmp/site/site ] || { mkdir -p /tmp/site && tar -xJf .gpu/site.tar.xz -C /tmp/site; }
[ -d /tmp/site/site/sapien/sensor ] || tar -xJf .gpu/oidn.tar.xz -C /tmp/site/site
python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site/site .gpu/*.whl
if [ -f .gpu/physx/libPhysXGpu_64.so ]; then
  v=$(PYTHONPATH=/tmp/site/site python3 -c "import sapien.physx as p; print(p.version())")
  mkdir -p ~/.sapien/physx/$v && cp .gpu/physx/libPhysXGpu_64.so ~/.sapien/physx/$v/
fi
export PYTHONPATH=/tmp/site/site:$PWD
export MS_SKIP_ASSET_DOWNLOAD_PROMPT=1 PYTHONUNBUFFERED=1 EMBODIED_ENVS_CACHE=/tmp/eecache
