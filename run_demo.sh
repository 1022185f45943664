#!/usr/bin/env bash
# The main job on built-in defaults; creates .venv on first use. Output goes to ./out/.
set -euo pipefail
cd "$(dirname "$0")"
source scripts/bootstrap.sh
exec "$(dirname "$VENV_PYTHON")/tissue-sim" demo --out out "$@"
