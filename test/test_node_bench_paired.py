"""node-bench --against: the pair figures from CPUs whose ratios are known, the revision exported
as git has it, the runs alternated and resumed, and (slow) two real node-bench runs compared."""
import csv
import json
import subprocess
from pathlib import Path

import pytest

from tissue_sim_ros.analysis import node_bench_paired as paired

ROOT = Path(__file__).resolve().parents[1]
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
    assert paired.export_revision('HEAD', tmp_path / 'rev') == head
    assert (tmp_path / 'rev' / 'setup.py').read_text() == setup
    assert (tmp_path / 'rev' / 'tissue_sim_ros' / '__init__.py').is_file()
    (tmp_path / 'rev' / 'setup.py').write_text('changed')     # a second call keeps what is there
    assert paired.export_revision(head[:12], tmp_path / 'rev') == head
    assert (tmp_path / 'rev' / 'setup.py').read_text() == 'changed'
    # over another revision's export every file is replaced (one HEAD lacks does not stay)
    (tmp_path / 'rev' / 'stray.txt').write_text('')
    (tmp_path / 'rev' / 'COMMIT').write_text('0' * 40 + '\n')
    assert paired.export_revision('HEAD', tmp_path / 'rev') == head
    assert not (tmp_path / 'rev' / 'stray.txt').exists()
    assert (tmp_path / 'rev' / 'setup.py').read_text() == setup
    with pytest.raises(paired.PairedBenchError, match="'no-such-revision'"):
        paired.export_revision('no-such-revision', tmp_path / 'other')


@needs_git
def test_runs_alternate_which_goes_first_and_a_run_already_there_is_reused(tmp_path, monkeypatch):
    calls = []

    def fake_bench(tree, run_dir, bench_args):
        result_file = run_dir / 'node_bench.json'
        if result_file.is_file():
            return json.loads(result_file.read_text())
        version = 'before' if tree == tmp_path / 'out' / 'revision' else 'after'
        calls.append((run_dir.name, version))
        cpu = {'before': 90.0, 'after': 45.0}[version] + len(calls)
        result = {'node_cpu_pct_of_one_core': cpu, 'wrench_rate_hz': 50.0, 'ticks': 100, 'missed_ticks': 0}
        run_dir.mkdir(parents=True)
        result_file.write_text(json.dumps(result))
        return result

    monkeypatch.setattr(paired, '_bench_once', fake_bench)
    summary = paired.run('HEAD', str(tmp_path / 'out'), pairs=3, duration_s=1.0, stream=lambda *_: None)
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
    again = paired.run('HEAD', str(tmp_path / 'out'), pairs=3, duration_s=1.0, stream=lambda *_: None)
    assert len(calls) == 6 and again['ratios'] == summary['ratios']
    # but not another comparison in the same directory
    with pytest.raises(paired.PairedBenchError, match='another bench_args'):
        paired.run('HEAD', str(tmp_path / 'out'), pairs=3, duration_s=2.0, stream=lambda *_: None)


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
