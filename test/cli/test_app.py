"""The command line (cli/app.py): version and help, every refusal one error line naming what is
wrong, with exit status 2 and no traceback, and a study ended by Ctrl-C or SIGTERM at once,
resumable."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from support.processes import group_gone, wait_for
from tissue_sim_ros.analysis.synthetic_study import write_synthetic_study

BIN = Path(sys.executable).parent


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


STUDY_SCENE = ['mesh.generator=box', 'mesh.divisions=[6,6,5]', 'regions[0].membrane.criterion=none',
               'regions[0].friction.insertion_coulomb_n_per_m=10.57', 'regions[0].young_modulus_pa=20000.0',
               'regions[0].cutting_force_n=0.5']
FITS = ['regions[0].young_modulus_pa=5000:50000:log', 'regions[0].cutting_force_n=0.1:1.5']


@pytest.mark.parametrize('sig, status', [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_study_ends_at_once_on_a_signal_and_resumes(tmp_path, sig, status):
    """calibrate with two worker processes, signalled mid-search: it stops within 5 s (the
    running simulations dropped), no traceback, no worker left; run again, it reuses every
    evaluation it logged and logs none twice."""
    spec = write_synthetic_study(tmp_path / 'data', STUDY_SCENE, [3.0], travel_m=0.012, repeats=1, noise_n=0.005)
    out = tmp_path / 'out'
    command = [str(BIN / 'tissue-sim'), 'calibrate', '--data-spec', str(spec), '--jobs', '2',
               '--max-evaluations', '30', '--out', str(out)]
    for text in STUDY_SCENE:
        command += ['--set', text.replace('20000.0', '13000.0').replace('=0.5', '=0.3')]
    for text in FITS:
        command += ['--fit', text]
    # a user's Ctrl-C reaches a foreground process; a test run from a background job inherits
    # SIGINT ignored (POSIX), which Python keeps: give the study the foreground's default
    study = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                             start_new_session=True,
                             preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    evaluations = out / 'evaluations.jsonl'
    try:
        wait_for(lambda: (evaluations.exists() and len(evaluations.read_text().splitlines()) >= 2)
                  or study.poll() is not None, 300, 'two evaluations')
        assert study.poll() is None, study.communicate()[1]
        sent = time.monotonic()
        os.killpg(study.pid, sig)
        _, err = study.communicate(timeout=30)
        ended_s = time.monotonic() - sent
        assert group_gone(study.pid, 5.0), 'a worker outlived the study'
    finally:
        if study.poll() is None:
            os.killpg(study.pid, signal.SIGKILL)
    print(f'calibrate ended {ended_s:.2f} s after {signal.Signals(sig).name}')
    assert study.returncode == status and ended_s < 5.0, err[-2000:]
    assert 'Traceback' not in err and err.strip().splitlines()[-1].startswith('tissue-sim calibrate: '), err[-2000:]
    logged = len(evaluations.read_text().splitlines())
    again = subprocess.run(command, capture_output=True, text=True, timeout=900)
    assert again.returncode == 0, again.stderr[-2000:]
    keys = [json.dumps([json.loads(line)['values'], json.loads(line)['phases']], sort_keys=True)
            for line in evaluations.read_text().splitlines()]
    assert len(keys) == len(set(keys)) >= logged          # nothing evaluated twice
