"""node-bench --against: the pair figures from CPUs whose ratios are known, the revision exported
as git has it, the runs alternated and resumed, and (slow) two real node-bench runs compared."""

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from support.paths import ROOT
from tissue_sim_ros.bench import node_bench_paired as paired

needs_git = pytest.mark.skipif(not (ROOT / '.git').exists(), reason='needs a git checkout')


def _rows(before, after):
    return ([{'pair': k, 'version': 'before', 'node_cpu_pct_of_one_core': c} for k, c in enumerate(before)]
            + [{'pair': k, 'version': 'after', 'node_cpu_pct_of_one_core': c} for k, c in enumerate(after)])


def test_summary_of_pairs_whose_ratios_are_known():
    s = paired.summarise(_rows([80.0, 100.0, 50.0], [40.0, 70.0, 30.0]))
    assert s['pairs'] == 3
    assert s['ratios'] == pytest.approx([0.5, 0.7, 0.6])
    assert s['ratio_median'] == pytest.approx(0.6) and s['ratio_mean'] == pytest.approx(0.6)
    assert (s['ratio_min'], s['ratio_max']) == pytest.approx((0.5, 0.7))
    assert s['ratio_of_means'] == pytest.approx(140.0 / 230.0)
    # a pair with one run only does not count
    assert paired.summarise(_rows([80.0, 100.0], [40.0]))['pairs'] == 1
    with pytest.raises(ValueError, match='no complete pair'):
        paired.summarise(_rows([80.0], []))


@needs_git
def test_the_revision_is_exported_as_git_has_it_and_once(tmp_path):
    head = subprocess.run(['git', '-C', str(ROOT), 'rev-parse', 'HEAD'], capture_output=True, text=True,
                          check=True).stdout.strip()
    setup = subprocess.run(['git', '-C', str(ROOT), 'show', 'HEAD:setup.py'], capture_output=True, text=True,
                           check=True).stdout
    assert paired.resolve_commit('HEAD') == head and paired.resolve_commit(head[:12]) == head
    paired.export_revision(head, tmp_path / 'rev')
    assert (tmp_path / 'rev' / 'setup.py').read_text() == setup
    assert (tmp_path / 'rev' / 'tissue_sim_ros' / '__init__.py').is_file()
    (tmp_path / 'rev' / 'setup.py').write_text('changed')     # a second call keeps what is there
    paired.export_revision(head, tmp_path / 'rev')
    assert (tmp_path / 'rev' / 'setup.py').read_text() == 'changed'
    # over another revision's export every file is replaced (one HEAD lacks does not stay)
    (tmp_path / 'rev' / 'stray.txt').write_text('')
    (tmp_path / 'rev' / 'COMMIT').write_text('0' * 40 + '\n')
    paired.export_revision(head, tmp_path / 'rev')
    assert not (tmp_path / 'rev' / 'stray.txt').exists()
    assert (tmp_path / 'rev' / 'setup.py').read_text() == setup
    with pytest.raises(paired.BenchError, match="'no-such-revision'"):
        paired.resolve_commit('no-such-revision')


def test_a_child_that_imports_the_package_from_elsewhere_refuses_to_run(tmp_path):
    """The check each run makes: pointed at a tree without the package, the child finds this
    checkout's (the editable install) and stops, naming both."""
    done = subprocess.run([sys.executable, '-c', paired._CHILD, str(tmp_path), 'node-bench', '--help'],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode != 0
    assert f'not from {tmp_path.resolve()}' in done.stderr and 'imported tissue_sim_ros from' in done.stderr


@needs_git
def test_runs_alternate_which_goes_first_resume_and_refuse_another_comparison(tmp_path, monkeypatch):
    """Each run a fake child that writes its node_bench.json where its --out says (relative to
    its working directory), with a relative DIR: the runs' order, the environment each version
    gets, the files written, a resume that runs nothing again, and a changed option refused."""
    real_run = subprocess.run
    calls = []

    def fake_run(command, **kw):
        if command[0] == 'git':
            return real_run(command, **kw)
        assert command[:3] == [sys.executable, '-c', paired._CHILD]
        tree, out = Path(command[3]), Path(kw['cwd']) / command[command.index('--out') + 1]
        version = 'after' if tree == ROOT else 'before'
        assert kw['env']['PYTHONPATH'].split(os.pathsep)[0] == str(tree)
        assert ('XDG_CACHE_HOME' in kw['env'] and kw['env']['XDG_CACHE_HOME'].endswith('cache')) == (
            version == 'before')
        assert Path(command[command.index('--scene-file') + 1]).is_file()
        calls.append((out.name, version))
        cpu = {'before': 90.0, 'after': 45.0}[version] + len(calls)
        (out / 'node_bench.json').write_text(json.dumps({'node_cpu_pct_of_one_core': cpu, 'node_exit_code': 0,
                                                         'wrench_rate_hz': 50.0, 'ticks': 100}))
        return subprocess.CompletedProcess(command, 0, 'ran\n', '')

    monkeypatch.setattr(paired.subprocess, 'run', fake_run)
    monkeypatch.chdir(tmp_path)
    summary = paired.run('HEAD', 'out', pairs=3, duration_s=1.0, stream=lambda *_: None)
    assert calls == [('pair1_before', 'before'), ('pair1_after', 'after'), ('pair2_after', 'after'),
                     ('pair2_before', 'before'), ('pair3_before', 'before'), ('pair3_after', 'after')]
    # CPUs 91, 47 | 48, 94 | 95, 51 (the call count is added): ratios from those
    assert summary['ratios'] == pytest.approx([47 / 91, 48 / 94, 51 / 95])
    with open(tmp_path / 'out' / 'paired.csv') as f:
        rows = list(csv.DictReader(f))
    assert [(r['pair'], r['version'], r['first']) for r in rows][:4] == [
        ('1', 'before', 'True'), ('1', 'after', 'False'), ('2', 'after', 'True'), ('2', 'before', 'False')]
    assert json.loads((tmp_path / 'out' / 'paired.json').read_text())['ratio_of_means'] == pytest.approx(
        (47 + 48 + 51) / (91 + 94 + 95))
    assert 'ratio of the means' in (tmp_path / 'out' / 'paired.md').read_text()
    assert (tmp_path / 'out' / 'paired.png').stat().st_size > 10_000
    # resumed: every run is there, none is run again, the figures are the same
    lines = []
    again = paired.run('HEAD', 'out', pairs=3, duration_s=1.0, stream=lines.append)
    assert len(calls) == 6 and again['ratios'] == summary['ratios']
    assert sum('(reused)' in line for line in lines) == 6
    # not another comparison over those runs
    with pytest.raises(paired.BenchError, match='another bench_args'):
        paired.run('HEAD', 'out', pairs=3, duration_s=2.0, stream=lambda *_: None)
    plan = tmp_path / 'out' / 'plan.json'
    plan.rename(tmp_path / 'plan.json')       # runs whose plan is gone are not taken either
    with pytest.raises(paired.BenchError, match='no plan.json'):
        paired.run('HEAD', 'out', pairs=3, duration_s=1.0, stream=lambda *_: None)
    (tmp_path / 'plan.json').rename(plan)
    # a run whose node did not exit cleanly is not taken
    (tmp_path / 'out' / 'runs' / 'pair1_after' / 'node_bench.json').write_text(
        json.dumps({'node_cpu_pct_of_one_core': 40.0, 'node_exit_code': -9}))
    with pytest.raises(paired.BenchError, match='pair1_after'):
        paired.run('HEAD', 'out', pairs=3, duration_s=1.0, stream=lambda *_: None)


@pytest.mark.slow
@needs_git
def test_two_real_runs_are_compared(tmp_path):
    """HEAD against this checkout, one pair of 1 s runs on a coarse scene: both runs' figures
    are in the CSV, the ratio is theirs, and a failed run would have named its output."""
    pytest.importorskip('rclpy')
    import yaml
    spec = yaml.safe_load((ROOT / 'config' / 'liver_sample.yaml').read_text())
    spec['mesh'] = {'generator': 'box', 'size_m': spec['mesh']['size_m'],
                    'origin_m': spec['mesh']['origin_m'], 'divisions': [4, 4, 3]}
    scene = tmp_path / 'coarse.yaml'
    scene.write_text(yaml.safe_dump(spec, sort_keys=False))
    summary = paired.run('HEAD', str(tmp_path / 'out'), pairs=1, duration_s=1.0, scene_file=str(scene),
                         stream=lambda *_: None)
    runs = {v: json.loads((tmp_path / 'out' / 'runs' / f'pair1_{v}' / 'node_bench.json').read_text())
            for v in ('before', 'after')}
    assert all(r['node_exit_code'] == 0 and r['node_cpu_pct_of_one_core'] > 0 for r in runs.values())
    assert summary['ratios'] == pytest.approx(
        [runs['after']['node_cpu_pct_of_one_core'] / runs['before']['node_cpu_pct_of_one_core']])
    assert summary['scene'] == str(scene)


def test_against_a_scene_runs_this_checkout_on_both_scenes_in_turn(tmp_path, monkeypatch):
    """--against-scene: both versions are this tree, the reference on its scene and the other on
    --scene, alternating; a missing scene or both comparisons at once are refused."""
    calls = []
    scenes = {'before': ROOT / 'config' / 'liver_sample.yaml', 'after': ROOT / 'config' / 'liver_sample_flexible.yaml'}

    def fake_run(command, **kw):
        if command[0] == 'git':
            return subprocess.CompletedProcess(command, 0, b'', b'')
        tree, out = Path(command[3]), Path(kw['cwd']) / command[command.index('--out') + 1]
        scene = Path(command[command.index('--scene-file') + 1])
        assert tree == ROOT and kw['env'].get('XDG_CACHE_HOME') == os.environ.get('XDG_CACHE_HOME')
        version = next(v for v, s in scenes.items() if s == scene)
        calls.append((out.name, version))
        (out / 'node_bench.json').write_text(json.dumps({'node_cpu_pct_of_one_core': {'before': 50.0, 'after': 60.0}[
            version], 'node_exit_code': 0, 'wrench_rate_hz': 50.0, 'ticks': 100}))
        return subprocess.CompletedProcess(command, 0, 'ran\n', '')

    monkeypatch.setattr(paired.subprocess, 'run', fake_run)
    summary = paired.run(None, tmp_path / 'out', pairs=2, duration_s=1.0, scene_file=str(scenes['after']),
                         against_scene=str(scenes['before']), stream=lambda *_: None)
    assert calls == [('pair1_before', 'before'), ('pair1_after', 'after'), ('pair2_after', 'after'),
                     ('pair2_before', 'before')]
    assert summary['ratios'] == pytest.approx([1.2, 1.2]) and summary['against'].startswith('scene ')
    assert 'goal' not in (tmp_path / 'out' / 'paired.md').read_text()       # a cost, not a revision's cut
    with pytest.raises(paired.BenchError, match='no such file'):
        paired.run(None, tmp_path / 'other', against_scene=str(tmp_path / 'none.yaml'), stream=lambda *_: None)
    with pytest.raises(paired.BenchError, match='one of'):
        paired.run('HEAD', tmp_path / 'other', against_scene=str(scenes['before']), stream=lambda *_: None)
