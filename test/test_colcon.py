"""The package as ROS users build it: `colcon build` and `colcon test` on a copy of the sources.

colcon comes from PyPI with the ROS wheels (requirements.txt). The copy holds the files git
tracks or would track (not .venv, build outputs or logs), in a temporary workspace
``src/tissue_sim_ros``; the build installs there, and the installed entry point and data files
are used from that install tree, not from this checkout."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # about 15 s here

from support.paths import ROOT  # noqa: E402

BIN = Path(sys.executable).parent


def _sources():
    if shutil.which('git') is None or not (ROOT / '.git').exists():
        pytest.skip('not a git checkout: cannot tell sources from build outputs')
    out = subprocess.run(['git', 'ls-files', '-z', '--cached', '--others', '--exclude-standard'],
                         cwd=ROOT, capture_output=True, check=True).stdout
    return [p for p in out.decode().split('\0') if p and (ROOT / p).is_file()]


def test_colcon_build_installs_and_colcon_test_passes(tmp_path):
    colcon = BIN / 'colcon'
    if not colcon.exists():
        pytest.skip('colcon is not installed in this environment (requirements.txt has it)')
    src = tmp_path / 'src' / 'tissue_sim_ros'
    for rel in _sources():
        (src / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / rel, src / rel)
    env = dict(os.environ, PATH=f'{BIN}{os.pathsep}{os.environ.get("PATH", "")}',
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_DOMAIN_ID='97')
    build = subprocess.run([str(colcon), 'build'], cwd=tmp_path, env=env, capture_output=True,
                           text=True, timeout=300)
    assert build.returncode == 0, build.stdout + build.stderr
    assert 'Summary: 1 package finished' in build.stdout

    install = tmp_path / 'install' / 'tissue_sim_ros'
    share = install / 'share' / 'tissue_sim_ros'
    assert (install / 'share' / 'ament_index' / 'resource_index' / 'packages' /
            'tissue_sim_ros').is_file()
    for rel in ('package.xml', 'config/tissue_sim.yaml', 'config/liver_sample.yaml',
                'launch/tissue_sim.launch.py',
                'rviz/tissue_sim.rviz', 'foxglove/tissue_sim.json'):
        assert (share / rel).is_file(), rel
    assert sorted(p.name for p in (share / 'msg_examples').glob('*.yaml')) == \
        sorted(p.name for p in (ROOT / 'msg_examples').glob('*.yaml'))
    for script in ('tissue_sim_node', 'tissue-sim'):  # where `ros2 run` looks
        assert (install / 'lib' / 'tissue_sim_ros' / script).is_file(), script

    # the installed package, run from elsewhere (the source tree is not on the path)
    site = next((install / 'lib').glob('python3*/site-packages'))
    run_env = dict(env, PYTHONPATH=str(site), AMENT_PREFIX_PATH=str(install))
    probe = subprocess.run(
        [sys.executable, '-c', 'import tissue_sim_ros.ros.node as n; print(n.__file__)'],
        cwd=tmp_path, env=run_env, capture_output=True, text=True, timeout=120)
    assert probe.returncode == 0, probe.stderr
    assert Path(probe.stdout.strip()).is_relative_to(install)
    helped = subprocess.run([sys.executable, str(install / 'lib' / 'tissue_sim_ros' / 'tissue_sim_node'),
                             '--help'], cwd=tmp_path, env=run_env, capture_output=True, text=True,
                            timeout=120)
    assert helped.returncode == 0 and 'publish_rate_hz' in helped.stdout, helped.stderr

    # colcon test runs pytest (extras_require test) on the copy; a fast subset of the suite
    tested = subprocess.run([str(colcon), 'test', '--pytest-args', 'test/ros/messages/test_conversions.py'],
                            cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert tested.returncode == 0, tested.stdout + tested.stderr
    result = subprocess.run([str(colcon), 'test-result', '--all'], cwd=tmp_path, env=env,
                            capture_output=True, text=True, timeout=60)
    summary = [line for line in result.stdout.splitlines() if line.startswith('Summary:')]
    assert result.returncode == 0 and summary, result.stdout
    counts = dict(part.strip().split(' ')[::-1] for part in summary[0][len('Summary:'):].split(','))
    assert int(counts['tests']) >= 20
    assert counts['errors'] == '0' and counts['failures'] == '0'
