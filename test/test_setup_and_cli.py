"""The documentation's promises: docs/engine.md's first Python example runs, the CLI answers, and
the set-up script finds a working Python 3.12 (skipping shims that refuse to run) or names what it
needs."""
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import tissue_sim_ros

ROOT = Path(__file__).resolve().parents[1]


def test_engine_page_python_example_runs():
    code = re.findall(r'```python\n(.*?)```', (ROOT / 'docs' / 'engine.md').read_text(), re.S)[0]
    namespace = {}
    exec(compile(code, 'docs/engine.md', 'exec'), namespace)
    sim = namespace['sim']
    assert sim.step_count == 100 and sim.reaction_force(namespace['top'])[2] > 0.0


def test_cli_version_and_help():
    from tissue_sim_ros.cli import app as cli
    with pytest.raises(SystemExit) as version:
        cli.main(['--version'])
    assert version.value.code == 0
    help_text = cli.build_parser().format_help()
    for command in ('compress', 'bench'):
        assert command in help_text



def test_cli_reports_a_bad_scene_and_a_divergence_in_one_line(tmp_path, capsys, monkeypatch):
    """A scene with an unknown key, and a run whose simulation diverges: one error line naming
    it and exit status 2, no traceback."""
    from tissue_sim_ros.cli import app as cli
    from tissue_sim_ros.analysis import insert
    from tissue_sim_ros.errors import SimulationDiverged
    bad = tmp_path / 'bad.yaml'
    bad.write_text('needle:\n  diameter_mm: 2.4\n')
    assert cli.main(['insert', '--scene', str(bad), '--out', str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith('tissue-sim insert: error:') and 'diameter_mm' in err and 'Traceback' not in err

    def diverge(*args, **kwargs):
        raise SimulationDiverged('13 inverted elements (det F <= 0)', 2500, 5.83, 0.0023, 0.0029)
    monkeypatch.setattr(insert, 'run_insertion', diverge)
    assert cli.main(['insert', '--out', str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert 'diverged at step 2500' in err and 'model.geometric: true' in err

def test_insert_without_a_puncture_says_so_instead_of_nan(tmp_path, capsys):
    """The default scene's needle starts 9 mm above the surface: 12 mm of travel indents the
    capsule without puncturing it. The comparison with the bovine liver says there is no puncture
    to compare, not '+nan mm and +nan N off'."""
    from tissue_sim_ros.cli import app as cli
    assert cli.main(['insert', '--travel-mm', '12', '--speed-mm-s', '10', '--set', 'mesh.fine_size_m=0.003',
                     '--set', 'mesh.divisions=[6,6,5]', '--out', str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert 'no puncture in this run' in out and 'nan' not in out


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
    from tissue_sim_ros.cli import app as cli
    cli.main(['compress', '--out', str(tmp_path), '--strain', '0.03', '--speed-mm-s', '5'])
    assert (tmp_path / 'compression.png').stat().st_size > 10_000
    out = capsys.readouterr().out
    final = float(re.search(r'final reaction ([0-9.]+) N', out).group(1))
    # 0.05 x 0.05 block, 0.03 high, E = 5 kPa: E A strain = 0.375 N at 3 %; slow plate, within 3 %
    assert final == pytest.approx(5e3 * 0.05 * 0.05 * 0.03, rel=0.03)


def _error_line(capsys, argv):
    """Run ``tissue-sim argv`` in this process; the one stderr line it printed, after checking
    exit status 2 and no traceback."""
    from tissue_sim_ros.cli import app as cli
    try:
        status = cli.main(argv)
    except SystemExit as exc:  # argparse refusing a value exits from parse_args
        status = exc.code
    err = capsys.readouterr().err
    assert status == 2, err
    assert 'Traceback' not in err and err.count('\n') == 1, err
    assert err.startswith(f'tissue-sim {argv[0]}: error: '), err
    return err


@pytest.mark.parametrize('argv, named', [
    (['insert', '--speed-mm-s', '-3'], ["--speed-mm-s: '-3'", '> 0']),
    (['insert', '--depth-mm', '-3'], ["--depth-mm: '-3'"]),
    (['insert', '--speed-mm-s', 'nan'], ["--speed-mm-s: 'nan'", 'finite']),
    (['insert', '--depth-mm', 'deep'], ["--depth-mm: 'deep'"]),
    (['drive', '--speed-mm-s', '0', '--depth-mm', '3'], ["--speed-mm-s: '0'"]),
    (['drive', '--speed-mm-s', '1', '--depth-mm', '-3'], ["--depth-mm: '-3'", '>= 0']),
    (['drive', '--speed-mm-s', '1', '--depth-mm', '3', '--rate-hz', '-100'], ["--rate-hz: '-100'"]),
    (['drive', '--speed-mm-s', '1', '--depth-mm', '3', '--hold-s', 'inf'], ["--hold-s: 'inf'"]),
    (['drive', '--speed-mm-s', '1'], ['--travel-mm', '--depth-mm', 'required']),
    (['insert', '--travel-mm', '3', '--depth-mm', '3'], ['--depth-mm', 'not allowed with', '--travel-mm']),
    (['insert', '--travel-mm', '0'], ["--travel-mm: '0'", '> 0']),
    (['insert', '--set', 'solver.mass_scaling'], ["--set 'solver.mass_scaling'", 'KEY=VALUE']),
    (['insert', '--set', 'regions[kidney].young_modulus_pa=1'], ["no entry of regions named 'kidney'"]),
    (['drive', '--speed-mm-s', '1', '--travel-mm', '2'], ['--travel-mm 2', 'start height']),
    (['demo', '--speed-mm-s', '-5'], ["--speed-mm-s: '-5'"]),
    (['demo', '--depth-mm', '-15'], ["--depth-mm: '-15'"]),
    (['compress', '--strain', '1.2'], ["--strain: '1.2'", '< 1']),
    (['compress', '--speed-mm-s', '0'], ["--speed-mm-s: '0'"]),
    (['node-bench', '--duration-s', '-1'], ["--duration-s: '-1'", '>= 1']),
    (['node-bench', '--load', '-1'], ["--load: '-1'", 'whole number >= 0']),
    (['node-bench', '--load', 'two'], ["--load: 'two'"]),
    (['node-bench', '--threads', '-1'], ["--threads: '-1'"]),
    (['node-bench', '--executor', 'fast'], ["--executor: invalid choice: 'fast'"]),
    (['bench', '--models', 'full', 'fastest'], ['--models fastest: unknown', 'full+visc']),
])
def test_cli_refuses_impossible_values_in_one_line(capsys, argv, named):
    err = _error_line(capsys, argv)
    for words in named:
        assert words in err


def test_cli_names_a_missing_or_unusable_file(tmp_path, capsys):
    """Scene files that are missing or a directory, an --out that is a file or lies below one,
    a scene whose mesh.file is missing or whose YAML is broken: one line naming the path."""
    a_file = tmp_path / 'a_file'
    a_file.write_text('not a directory')
    missing_mesh = tmp_path / 'missing_mesh.yaml'
    missing_mesh.write_text(f'mesh:\n  generator: file\n  file: {tmp_path / "nowhere.msh"}\n')
    broken = tmp_path / 'broken.yaml'
    broken.write_text('mesh: [1, 2\n')
    cases = [
        (['insert', '--scene', str(tmp_path / 'none.yaml')], [str(tmp_path / 'none.yaml'), 'no such file']),
        (['insert', '--scene', str(tmp_path)], [str(tmp_path), 'not a file']),
        (['drive', '--speed-mm-s', '1', '--depth-mm', '1', '--scene-file', str(tmp_path / 'x.yaml')],
         [str(tmp_path / 'x.yaml')]),
        (['insert', '--out', str(a_file)], [str(a_file), 'expected a directory']),
        (['compress', '--out', str(a_file / 'below')], [str(a_file), 'is a file']),
        (['node-bench', '--out', str(a_file)], [str(a_file)]),
        (['insert', '--scene', str(missing_mesh), '--out', str(tmp_path)], [str(tmp_path / 'nowhere.msh')]),
        (['insert', '--scene', str(broken), '--out', str(tmp_path)], ['broken.yaml', 'not valid YAML']),
    ]
    for argv, named in cases:
        err = _error_line(capsys, argv)
        for words in named:
            assert words in err, (argv, err)


def test_cli_names_the_file_an_os_error_is_about(tmp_path, capsys):
    """demo's log folder is a file already: the OSError becomes one line with that path."""
    (tmp_path / 'logs').write_text('in the way')
    err = _error_line(capsys, ['demo', '--out', str(tmp_path)])
    assert str(tmp_path / 'logs') in err and 'File exists' in err


def test_console_script_missing_mesh_file_is_one_line(tmp_path):
    """The issue's case, as a user runs it: insert on a scene whose mesh.file does not exist."""
    scene = tmp_path / 'scene.yaml'
    scene.write_text('mesh:\n  generator: file\n  file: liver.vtu\n')
    result = subprocess.run([str(Path(sys.executable).parent / 'tissue-sim'), 'insert', '--scene',
                             str(scene), '--out', str(tmp_path)],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 2
    assert result.stderr == f"tissue-sim insert: error: mesh file '{tmp_path / 'liver.vtu'}' does not exist\n"
