#!/usr/bin/env bash
# Set up (if needed) and run the test suite, on every core.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
export MS_SKIP_ASSET_DOWNLOAD_PROMPT=1
.venv/bin/python -m ruff check embodied_envs tests tools
# one pytest worker per core (pytest-xdist), a test file's tests on one worker: module fixtures
# are built once and tests that share a resource (the Ray cluster) never run side by side.
# TEST_WORKERS=0 runs in this process.
exec .venv/bin/python -m pytest -q -p no:cacheprovider -n "${TEST_WORKERS:-auto}" --dist loadfile "$@"
