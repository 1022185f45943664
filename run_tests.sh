#!/usr/bin/env bash
# Runs the test suite; creates .venv on first use. Extra arguments go to pytest; a test file or
# folder among them replaces the default test/ (./run_tests.sh -q test/engine/needle/test_tip.py).
set -euo pipefail
cd "$(dirname "$0")"
source scripts/bootstrap.sh
for arg in "$@"; do
    if [[ "$arg" != -* && -e "${arg%%::*}" ]]; then exec "$VENV_PYTHON" -m pytest "$@"; fi
done
exec "$VENV_PYTHON" -m pytest test "$@"
