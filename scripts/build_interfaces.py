"""Build the interface packages under interfaces/ into a Python environment built from the ROS 2 wheels.

Run by scripts/bootstrap.sh with the environment's interpreter (``python scripts/build_interfaces.py``);
standard library only (numpy for its include directory). What it does, and says as it goes:

1. chooses the packages: ``tissue_sim_msgs`` always; ``tf2_msgs`` (TFMessage only) only where no
   tf2_msgs is importable, or where the importable one is the one this script built before (a ROS
   install has the real one, which is never replaced);
2. points the wheels' exported CMake files from the wheel builder's Python (``/opt/python/...``:
   its headers and numpy's) to this interpreter's, so that the generated C extensions compile here;
3. runs ``colcon build --merge-install`` with the environment's own prefix as the install base, so
   the generated Python packages land in its site-packages and their libraries in its ``lib/``,
   where the wheels' start-up hook already points the dynamic loader for every interpreter the
   environment starts (the node, its prediction workers, test subprocesses): nothing to set before
   Python starts. The build tree goes to ``<prefix>/interfaces/``.

Exit status 0 when every package built (or nothing needed building), 1 with the build's log tail
otherwise. ``--check``: only print what would be built.
"""
from __future__ import annotations

import importlib.util
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
INTERFACES = ROOT / 'interfaces'
PREFIX = Path(sys.prefix)
BUILD = PREFIX / 'interfaces'
#: the wheel builder's Python, as the wheels' CMake exports name it
_BUILDER_PATH = re.compile(r'/opt/python/cp3\d+-cp3\d+/[^;"\s)]*')


def say(text: str) -> None:
    print(f'interfaces: {text}', file=sys.stderr, flush=True)


def packages() -> list[str]:
    """The interface packages to build here (see the module docstring)."""
    chosen = ['tissue_sim_msgs']
    spec = importlib.util.find_spec('tf2_msgs')
    ours = spec is not None and spec.origin is not None and \
        (PREFIX / 'share' / 'tf2_msgs' / 'tissue_sim_ros_built').is_file()
    if spec is None or ours:
        chosen.insert(0, 'tf2_msgs')
    else:
        say(f'tf2_msgs is installed ({Path(spec.origin).parent}): not built')
    return chosen


def _replacement(path: str, include: str, numpy_include: str) -> str:
    if re.search(r'/include/python3\.\d+$', path):
        return include
    if path.endswith('numpy/_core/include') or path.endswith('numpy/core/include'):
        return numpy_include
    return path


def fix_cmake_exports() -> int:
    """Point the exported CMake files at this interpreter's headers; the files changed."""
    import numpy
    include = sysconfig.get_paths()['include']
    if not (Path(include) / 'Python.h').is_file():
        raise SystemExit(f'interfaces: {include}/Python.h is missing: this Python has no development '
                         'headers (Debian/Ubuntu: apt install python3.12-dev)')
    changed = 0
    for path in sorted((PREFIX / 'share').glob('*/cmake/*.cmake')):
        text = path.read_text()
        fixed = _BUILDER_PATH.sub(lambda m: _replacement(m.group(0), include, numpy.get_include()), text)
        if fixed != text:
            path.write_text(fixed)
            changed += 1
    return changed


def build(names: list[str]) -> int:
    colcon = PREFIX / 'bin' / 'colcon'
    for tool in ('cmake', 'cc'):
        if shutil.which(tool) is None and not (tool == 'cc' and shutil.which('gcc')):
            say(f'{tool} is not on PATH: the interface packages need CMake and a C/C++ compiler '
                '(Debian/Ubuntu: apt install cmake build-essential)')
            return 1
    env = dict(os.environ, AMENT_PREFIX_PATH=str(PREFIX), CMAKE_PREFIX_PATH=str(PREFIX),
               PATH=f'{PREFIX / "bin"}{os.pathsep}{os.environ.get("PATH", "")}',
               PYTHONWARNINGS='ignore')
    env.pop('COLCON_PREFIX_PATH', None)
    command = [str(colcon), '--log-base', str(BUILD / 'log'), 'build', '--base-paths', str(INTERFACES),
               '--packages-select', *names, '--build-base', str(BUILD / 'build'),
               '--install-base', str(PREFIX), '--merge-install', '--event-handlers', 'console_cohesion-',
               'console_start_end-', 'status-', '--cmake-args', '-DBUILD_TESTING=OFF',
               f'-DPython3_EXECUTABLE={sys.executable}', '-DCMAKE_BUILD_TYPE=Release']
    started = time.monotonic()
    done = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        say(f'colcon build failed ({done.returncode}):\n' + (done.stdout + done.stderr)[-4000:])
        say(f'the whole log: {BUILD / "log" / "latest_build"}')
        return 1
    if 'tf2_msgs' in names:
        (PREFIX / 'share' / 'tf2_msgs' / 'tissue_sim_ros_built').write_text(
            'built by tissue_sim_ros scripts/build_interfaces.py (TFMessage only)\n')
    say(f'built {", ".join(names)} in {time.monotonic() - started:.0f} s')
    return 0


def main(argv: list[str]) -> int:
    names = packages()
    if '--check' in argv:
        print(' '.join(names))
        return 0
    say(f'building {", ".join(names)} into {PREFIX} (colcon, CMake; about half a minute)')
    changed = fix_cmake_exports()
    if changed:
        say(f"{changed} CMake export files now name this Python's headers")
    return build(names)


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
