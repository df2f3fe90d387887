#!/usr/bin/env bash
# Set up (if needed) and run the test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
export MS_SKIP_ASSET_DOWNLOAD_PROMPT=1
.venv/bin/python -m ruff check embodied_envs tests tools
exec .venv/bin/python -m pytest -q -p no:cacheprovider "$@"
