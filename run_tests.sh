#!/usr/bin/env bash
# Runs the test suite; creates .venv on first use. Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")"
source scripts/bootstrap.sh
exec "$VENV_PYTHON" -m pytest test "$@"
