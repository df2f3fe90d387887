#!/usr/bin/env bash
# Write the lock, constraints.txt: every dependency's version as a fresh install resolves it
# today. Run it on purpose (after a change of pyproject.toml's dependencies, or to take newer
# releases), then run the tests and commit constraints.txt with the change.
# It runs tools/setup.sh without a lock into a new temporary venv (torch first, then the package
# with the extras setup.sh installs: everything comes from pyproject.toml), and writes
# `pip freeze --exclude-editable` of that venv under a temporary name, renamed when complete.
# PYTHON: the interpreter of the venv (default python3).
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
OUT=$ROOT/constraints.txt
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT

VENV=$TMP/venv LOCK=none bash tools/setup.sh
{
    echo "# The lock: every dependency's version, written by tools/lock.sh (do not edit by hand)."
    echo "# tools/setup.sh installs with it (pip install -c constraints.txt ...)."
    echo "# $("$TMP/venv/bin/python" --version), $(uname -m)"
    "$TMP/venv/bin/python" -m pip freeze --exclude-editable
} >"$TMP/constraints.txt"
grep -qE '^torch==' "$TMP/constraints.txt" || { echo "[lock] ERROR: no torch in the freeze" >&2; exit 1; }
mv "$TMP/constraints.txt" "$OUT.tmp"
mv "$OUT.tmp" "$OUT"
echo "[lock] wrote $OUT: $(grep -cvE '^#' "$OUT") packages" >&2
