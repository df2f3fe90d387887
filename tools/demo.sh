#!/usr/bin/env bash
# Set up (if needed) and run the demo on the shipped default layout; videos go to outputs/demo.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
export MS_SKIP_ASSET_DOWNLOAD_PROMPT=1
exec .venv/bin/embodied-envs demo --out outputs/demo "$@"
