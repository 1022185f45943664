"""The documentation's promises and the console script: docs/engine.md's first Python example
runs, the set-up script finds a working Python 3.12 (skipping shims that refuse to run) or names
what it needs, and tissue-sim answers as installed."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

import tissue_sim_ros
from support.paths import ROOT


def test_engine_page_python_example_runs():
    code = re.findall(r'```python\n(.*?)```', (ROOT / 'docs' / 'engine.md').read_text(), re.S)[0]
    namespace = {}
    exec(compile(code, 'docs/engine.md', 'exec'), namespace)
    sim = namespace['sim']
    assert sim.step_count == 100 and sim.reaction_force(namespace['top'])[2] > 0.0


def test_console_script_prints_version():
    script = Path(sys.executable).parent / 'tissue-sim'
    result = subprocess.run([str(script), '--version'], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0
    assert result.stdout.strip() == f'tissue-sim {tissue_sim_ros.__version__}'


def _find_python(tmp_path, extra_path, pyenv_root):
    env = {'PATH': f'{extra_path}:/usr/bin:/bin', 'HOME': str(tmp_path), 'PYENV_ROOT': str(pyenv_root),
           'TISSUE_SIM_FIND_PYTHON_ONLY': '1'}
    return subprocess.run(['bash', '-c', f'source {ROOT}/scripts/bootstrap.sh'], env=env,
                          capture_output=True, text=True, timeout=60)


def test_bootstrap_skips_refusing_shim_and_finds_312(tmp_path):
    shims = tmp_path / 'shims'
    shims.mkdir()
    for name in ('python3.12', 'python3'):
        shim = shims / name
        shim.write_text('#!/bin/sh\necho "pyenv: python3.12: command not found" >&2\nexit 127\n')
        shim.chmod(0o755)
    real = Path(sys.base_prefix) / 'bin' / 'python3.12'
    if not real.exists():
        pytest.skip('no python3.12 under sys.base_prefix to stand in for a pyenv version')
    pyenv = tmp_path / 'pyenv'
    (pyenv / 'versions' / '3.12.9' / 'bin').mkdir(parents=True)
    (pyenv / 'versions' / '3.12.9' / 'bin' / 'python3.12').symlink_to(real)
    found = _find_python(tmp_path, shims, pyenv)
    assert found.returncode == 0, found.stderr
    assert found.stdout.strip() == str(pyenv / 'versions' / '3.12.9' / 'bin' / 'python3.12')


def test_bootstrap_names_what_it_needs_when_no_312(tmp_path):
    shims = tmp_path / 'shims'
    shims.mkdir()
    shim = shims / 'python3.12'
    shim.write_text('#!/bin/sh\nexit 127\n')
    shim.chmod(0o755)
    if any(Path(p).exists() for p in ('/usr/bin/python3.12', '/usr/local/bin/python3.12')):
        pytest.skip('this machine has a system python3.12, so the search cannot fail here')
    result = _find_python(tmp_path, shims, tmp_path / 'no-pyenv')
    if result.returncode == 0 and '3.12' in subprocess.run([result.stdout.strip(), '--version'],
                                                           capture_output=True, text=True).stdout:
        pytest.skip('/usr/bin/python3 is 3.12 on this machine')
    assert result.returncode == 1
    assert 'Python 3.12' in result.stderr


def test_console_script_missing_mesh_file_is_one_line(tmp_path):
    """The issue's case, as a user runs it: insert on a scene whose mesh.file does not exist."""
    scene = tmp_path / 'scene.yaml'
    scene.write_text('mesh:\n  generator: file\n  file: liver.vtu\n')
    result = subprocess.run([str(Path(sys.executable).parent / 'tissue-sim'), 'insert', '--scene',
                             str(scene), '--out', str(tmp_path)],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 2
    assert result.stderr == f"tissue-sim insert: error: mesh file '{tmp_path / 'liver.vtu'}' does not exist\n"
