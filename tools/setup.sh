#!/usr/bin/env bash
# Idempotent set-up: a .venv with torch (CPU build) first, the package with its dev and lerobot
# extras at the versions of the lock (constraints.txt, made by tools/lock.sh), and a Vulkan device
# for SAPIEN (lavapipe from bookworm-backports when none is found).
# Re-running only checks; it installs what is missing and nothing more.
# Overrides: PYTHON (the interpreter that makes the venv), VENV (its folder, default .venv),
# LOCK (the constraints file, default constraints.txt; LOCK=none: the newest versions
# pyproject.toml allows, as tools/lock.sh installs them to write the lock).
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
VENV=${VENV:-$ROOT/.venv}
PY=${PYTHON:-python3}
LOCK=${LOCK:-$ROOT/constraints.txt}
EXTRAS=dev,lerobot  # the extras installed (and locked by tools/lock.sh)
TORCH=torch==2.13.0  # without a lock: a CPU build on these machines (the lock pins its build)
export PIP_DISABLE_PIP_VERSION_CHECK=1

log() { printf '[setup] %s\n' "$*" >&2; }

CONSTRAIN=()
if [ "$LOCK" != none ]; then
    if [ ! -f "$LOCK" ]; then
        log "ERROR: no lock at $LOCK: run 'bash tools/lock.sh' to write it (or LOCK=none)."
        exit 1
    fi
    CONSTRAIN=(-c "$LOCK")
    # the lock's torch, build included (e.g. 2.13.0+cpu): never a CUDA build in its place
    TORCH=$(grep -m1 -E '^torch==' "$LOCK" || true)
    if [ -z "$TORCH" ]; then
        log "ERROR: $LOCK pins no torch: re-run 'bash tools/lock.sh'."
        exit 1
    fi
fi

if [ ! -x "$VENV/bin/python" ]; then
    log "creating $VENV"
    "$PY" -m venv "$VENV"
fi
VPY=$VENV/bin/python

# torch first: anything that pulls torch unpinned would otherwise fetch a multi-GB CUDA build.
# A lock's "+cpu" build needs a source that has it (a wheel folder or PyTorch's CPU index);
# without one pip stops with "No matching distribution" instead of fetching CUDA.
if ! "$VPY" -c "import torch" 2>/dev/null; then
    log "installing $TORCH"
    "$VPY" -m pip install -q "$TORCH"
fi

# Re-install the package only when pyproject.toml or the lock changed since the last install.
STAMP=$VENV/.embodied_envs.stamp
HASH=$(cat pyproject.toml "${CONSTRAIN[@]:1}" | sha256sum | cut -d' ' -f1)
if [ ! -f "$STAMP" ] || [ "$(cat "$STAMP")" != "$HASH" ] || ! "$VPY" -c "import embodied_envs" 2>/dev/null; then
    log "installing embodied-envs[$EXTRAS] (editable)${CONSTRAIN[*]:+, versions of ${LOCK#"$ROOT"/}}"
    "$VPY" -m pip install -q "${CONSTRAIN[@]}" -e ".[$EXTRAS]"
    echo "$HASH" >"$STAMP"
fi

# SAPIEN needs a Vulkan device even for state-only simulation.
probe_vulkan() {
    "$VPY" - <<'PYEOF' >/dev/null 2>&1
import sapien
sapien.render.RenderSystem()
PYEOF
}
if ! probe_vulkan; then
    if [ -f /etc/debian_version ] && command -v apt-get >/dev/null; then
        log "no Vulkan render device: installing Mesa lavapipe from bookworm-backports"
        SUDO=""
        [ "$(id -u)" -ne 0 ] && SUDO="sudo"
        SRC=/etc/apt/sources.list.d/bookworm-backports.list
        if ! grep -rqs "bookworm-backports" /etc/apt/sources.list /etc/apt/sources.list.d/; then
            echo "deb http://deb.debian.org/debian bookworm-backports main" | $SUDO tee "$SRC" >/dev/null
        fi
        $SUDO apt-get update -qq
        DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq -t bookworm-backports \
            mesa-vulkan-drivers libvulkan1 >/dev/null
        if ! probe_vulkan; then
            log "ERROR: SAPIEN still finds no Vulkan device after installing lavapipe."
            exit 1
        fi
    else
        log "ERROR: SAPIEN finds no Vulkan device. Install a Vulkan driver: Mesa's lavapipe"
        log "(mesa-vulkan-drivers >= 23, e.g. Debian bookworm-backports, Ubuntu 24.04) or your GPU's driver."
        exit 1
    fi
fi
log "ready: $("$VPY" -c 'import torch, mani_skill, numpy; print(f"torch {torch.__version__}, mani_skill {mani_skill.__version__}, numpy {numpy.__version__}")')"
