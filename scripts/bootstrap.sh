#!/usr/bin/env bash
# Source this file: it finds a working Python 3.12, creates .venv beside the repository root on
# first use (or when requirements.txt changed), installs the pinned dependencies and the package
# itself (editable), builds the interface packages under interfaces/ into it (tissue_sim_msgs, and
# tf2_msgs where no tf2_msgs is installed: scripts/build_interfaces.py; again when those files or the
# pins change), and leaves VENV_PYTHON pointing at the environment's interpreter.
set -euo pipefail
repo_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${TISSUE_SIM_VENV:-$repo_root/.venv}"

works_as_312() {  # a candidate counts only if it runs and reports 3.12 (pyenv shims may refuse)
  "$1" -c 'import sys, venv; sys.exit(0 if sys.version_info[:2] == (3, 12) else 1)' >/dev/null 2>&1
}

find_python312() {
  local c
  for c in "${TISSUE_SIM_PYTHON:-}" python3.12 python3 \
           "${PYENV_ROOT:-$HOME/.pyenv}"/versions/3.12*/bin/python3.12 \
           /usr/bin/python3.12 /usr/local/bin/python3.12 /opt/homebrew/bin/python3.12; do
    [ -n "$c" ] || continue
    if command -v "$c" >/dev/null 2>&1 && works_as_312 "$(command -v "$c")"; then
      command -v "$c"; return 0
    fi
  done
  return 1
}

if [ "${TISSUE_SIM_FIND_PYTHON_ONLY:-}" = 1 ]; then   # used by the tests
  find_python312 || { echo "error: no working Python 3.12 found" >&2; exit 1; }
  exit 0
fi

stamp="$venv/.requirements.sha256"
want="$(cat "$repo_root/requirements.txt" "$repo_root/setup.py" | sha256sum | cut -d' ' -f1)"
if [ ! -x "$venv/bin/python" ] || [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  if ! py="$(find_python312)"; then
    echo "error: tissue_sim_ros needs Python 3.12 (ROS 2 Jazzy's) with the venv module." >&2
    echo "  Tried: \$TISSUE_SIM_PYTHON, python3.12, python3, pyenv versions/3.12*/bin/python3.12," >&2
    echo "  /usr/bin/python3.12. Install it (Ubuntu 24.04: apt install python3 python3-venv)" >&2
    echo "  or set TISSUE_SIM_PYTHON=/path/to/python3.12." >&2
    exit 1
  fi
  echo "setting up $venv with $py ($("$py" --version 2>&1))" >&2
  [ -x "$venv/bin/python" ] || "$py" -m venv "$venv"
  "$venv/bin/python" -m pip install --quiet --upgrade pip >&2
  "$venv/bin/python" -m pip install --quiet -r "$repo_root/requirements.txt" >&2
  "$venv/bin/python" -m pip install --quiet --no-deps --no-build-isolation -e "$repo_root" >&2
  echo "$want" > "$stamp"
fi
interfaces_stamp="$venv/.interfaces.sha256"
interfaces_want="$(cd "$repo_root" && find interfaces scripts/build_interfaces.py requirements.txt -type f \
  -print0 | sort -z | xargs -0 sha256sum | sha256sum | cut -d' ' -f1)"
if [ "$(cat "$interfaces_stamp" 2>/dev/null)" != "$interfaces_want" ]; then
  echo "building the interface packages (interfaces/) into $venv" >&2
  "$venv/bin/python" "$repo_root/scripts/build_interfaces.py"
  echo "$interfaces_want" > "$interfaces_stamp"
fi
VENV_PYTHON="$venv/bin/python"
export VENV_PYTHON
