"""The README's promises: its Python example runs, the CLI answers, and the set-up script finds a
working Python 3.12 (skipping shims that refuse to run) or names what it needs."""
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import tissue_sim_ros

ROOT = Path(__file__).resolve().parents[1]


def test_readme_python_example_runs():
    code = re.findall(r'```python\n(.*?)```', (ROOT / 'README.md').read_text(), re.S)[0]
    namespace = {}
    exec(compile(code, 'README.md', 'exec'), namespace)
    sim = namespace['sim']
    assert sim.step_count == 100 and sim.reaction_force(namespace['top'])[2] > 0.0


def test_cli_version_and_help():
    from tissue_sim_ros import cli
    with pytest.raises(SystemExit) as version:
        cli.main(['--version'])
    assert version.value.code == 0
    help_text = cli.build_parser().format_help()
    for command in ('compress', 'bench'):
        assert command in help_text



def test_cli_reports_a_bad_scene_and_a_divergence_in_one_line(tmp_path, capsys, monkeypatch):
    """A scene with an unknown key, and a run whose simulation diverges: one error line naming
    it and exit status 2, no traceback."""
    from tissue_sim_ros import cli
    from tissue_sim_ros.analysis import insertion
    from tissue_sim_ros.engine.solver import SimulationDiverged
    bad = tmp_path / 'bad.yaml'
    bad.write_text('needle:\n  diameter_mm: 2.4\n')
    assert cli.main(['insert', '--scene', str(bad), '--out', str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith('tissue-sim insert: error:') and 'diameter_mm' in err and 'Traceback' not in err

    def diverge(*args, **kwargs):
        raise SimulationDiverged('13 inverted elements (det F <= 0)', 2500, 5.83, 0.0023, 0.0029)
    monkeypatch.setattr(insertion, 'run_insertion', diverge)
    assert cli.main(['insert', '--out', str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert 'diverged at step 2500' in err and 'model.geometric: true' in err

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


def test_compress_demo_writes_plot_and_tracks_E_A_strain(tmp_path, capsys):
    from tissue_sim_ros import cli
    cli.main(['compress', '--out', str(tmp_path), '--strain', '0.03', '--speed-mm-s', '5'])
    assert (tmp_path / 'compression.png').stat().st_size > 10_000
    out = capsys.readouterr().out
    final = float(re.search(r'final reaction ([0-9.]+) N', out).group(1))
    # 0.05 x 0.05 block, 0.03 high, E = 5 kPa: E A strain = 0.375 N at 3 %; slow plate, within 3 %
    assert final == pytest.approx(5e3 * 0.05 * 0.05 * 0.03, rel=0.03)
