"""Ctrl-C at a terminal (SIGINT to the whole process group) and SIGTERM: the node and a study end
within seconds, print no traceback, leave no worker process behind, and the study resumes
(system.process_pools, cli.app, ros.predictions, analysis.jobs)."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tissue_sim_ros.analysis.synthetic_study import write_synthetic_study

BIN = Path(sys.executable).parent
STUDY_SCENE = ['mesh.generator=box', 'mesh.divisions=[6,6,5]', 'regions[0].membrane.criterion=none',
               'regions[0].friction.insertion_coulomb_n_per_m=10.57', 'regions[0].young_modulus_pa=20000.0',
               'regions[0].cutting_force_n=0.5']
FITS = ['regions[0].young_modulus_pa=5000:50000:log', 'regions[0].cutting_force_n=0.1:1.5']


def _group_gone(pgid: int, timeout_s: float) -> bool:
    """Whether every process of the group has ended within ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.05)
    return False


def _wait_for(condition, timeout_s: float, what: str):
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f'{what}: not within {timeout_s} s'
        time.sleep(0.05)


def test_ctrl_c_ends_the_node_and_its_prediction_workers_quietly(tmp_path):
    pytest.importorskip('rclpy')
    from tissue_sim_ros.ros.clients.node_process import console_script, private_ros_env
    log = tmp_path / 'node.log'
    command = console_script('tissue_sim_node', 'tissue_sim_ros.cli.node_script') + [
        '--ros-args', '-p', 'prediction.workers:=2', '-p', 'prediction.prestart:=true']
    with open(log, 'w') as out:
        node = subprocess.Popen(command, env=private_ros_env(170 + os.getpid() % 20), stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True)
    try:
        _wait_for(lambda: 'ticking' in log.read_text() or node.poll() is not None, 300, 'the node ticking')
        time.sleep(0.3)                              # the workers in their start-up (spawned, warming up)
        sent = time.monotonic()
        os.killpg(node.pid, signal.SIGINT)           # as a terminal's Ctrl-C: the whole group
        node.wait(timeout=30)
        ended_s = time.monotonic() - sent
        assert _group_gone(node.pid, 5.0), 'a worker outlived the node'
    finally:
        if node.poll() is None:
            os.killpg(node.pid, signal.SIGKILL)
    text = log.read_text()
    print(f'node and workers ended {ended_s:.2f} s after SIGINT')
    assert node.returncode == 0 and ended_s < 5.0, text[-2000:]
    assert 'Traceback' not in text and 'KeyboardInterrupt' not in text, text[-2000:]


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
    study = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                             start_new_session=True)
    evaluations = out / 'evaluations.jsonl'
    try:
        _wait_for(lambda: (evaluations.exists() and len(evaluations.read_text().splitlines()) >= 2)
                  or study.poll() is not None, 300, 'two evaluations')
        assert study.poll() is None, study.communicate()[1]
        sent = time.monotonic()
        os.killpg(study.pid, sig)
        _, err = study.communicate(timeout=30)
        ended_s = time.monotonic() - sent
        assert _group_gone(study.pid, 5.0), 'a worker outlived the study'
    finally:
        if study.poll() is None:
            os.killpg(study.pid, signal.SIGKILL)
    print(f'calibrate ended {ended_s:.2f} s after {signal.Signals(sig).name}')
    assert study.returncode == status and ended_s < 5.0, err[-2000:]
    assert 'Traceback' not in err and err.strip().splitlines()[-1].startswith('tissue-sim calibrate: '), err[-2000:]
    logged = len(evaluations.read_text().splitlines())
    again = subprocess.run(command, capture_output=True, text=True, timeout=900)
    assert again.returncode == 0, again.stderr[-2000:]
    import json
    keys = [json.dumps([json.loads(line)['values'], json.loads(line)['phases']], sort_keys=True)
            for line in evaluations.read_text().splitlines()]
    assert len(keys) == len(set(keys)) >= logged          # nothing evaluated twice
