"""``tissue-sim node-bench --against REV --out DIR``: this checkout's node against an earlier
revision's, on one scene, in alternating runs, for a before/after figure on a shared machine.

Why paired: on the 2-core VM these figures come from, the same node's CPU went from 48 % to 75 %
of a core within an hour (other tenants); one run of each, taken at different times, cannot show
a change of a third. Each pair runs both versions back to back, the first of the two alternating
from pair to pair, and the figures are the ratio within each pair (median and range) and the
ratio of the mean CPUs.

The earlier revision is exported with ``git archive`` into DIR/revision and run from there (first
on PYTHONPATH) in this same virtual environment, so its dependencies must still be installed;
each version runs its own ``tissue-sim node-bench``. Both run the same scene: by default the
earlier revision's packaged one, which the older engine is sure to read. Each run keeps its
``node_bench.json`` and console output in DIR/runs/; a run already there is reused (resume).
Writes paired.csv (one row per run), paired.json, paired.md and paired.png.
"""
from __future__ import annotations

import csv
import io
import json
import os
import shutil
import statistics
import subprocess
import sys
import tarfile
from pathlib import Path

import tissue_sim_ros

__all__ = ['run', 'summarise', 'export_revision', 'PairedBenchError']

#: figures kept per run (node_bench.json keys both versions write; the kernel share only newer ones)
COLUMNS = ('node_cpu_pct_of_one_core', 'kernel_share_of_node_cpu', 'wrench_rate_hz',
           'tick_period_dev_ms_p99', 'latency_ms_p99', 'missed_ticks', 'ticks')
CPU_GOAL_RATIO = 0.6   # issue 19: the node's CPU at most 60 % of what it was


class PairedBenchError(ValueError):
    """A revision that is not there, or a run of either version that failed (its output named)."""


def _this_tree() -> Path:
    return Path(tissue_sim_ros.__file__).resolve().parents[1]


def export_revision(rev: str, into: Path) -> str:
    """Write the files of commit ``rev`` of this checkout's repository into ``into``; returns its
    full hash. PairedBenchError when this is not a git checkout or ``rev`` names no commit."""
    root = _this_tree()
    found = subprocess.run(['git', '-C', str(root), 'rev-parse', '--verify', '--quiet', f'{rev}^{{commit}}'],
                           capture_output=True, text=True)
    if found.returncode != 0:
        raise PairedBenchError(f'--against {rev!r}: no such commit in {root} (a git checkout is needed)')
    commit = found.stdout.strip()
    if (into / 'COMMIT').is_file() and (into / 'COMMIT').read_text().strip() == commit:
        return commit
    if into.exists():
        shutil.rmtree(into)      # another revision's files: none of them may stay
    into.mkdir(parents=True)
    archive = subprocess.run(['git', '-C', str(root), 'archive', '--format=tar', commit],
                             capture_output=True, check=True)
    with tarfile.open(fileobj=io.BytesIO(archive.stdout)) as tar:
        tar.extractall(into, filter='data')
    (into / 'COMMIT').write_text(commit + '\n')
    return commit


def _bench_once(tree: Path, run_dir: Path, bench_args: list[str]) -> dict:
    """One ``tissue-sim node-bench`` of the package in ``tree``; its node_bench.json."""
    result_file = run_dir / 'node_bench.json'
    if result_file.is_file():
        return json.loads(result_file.read_text())
    run_dir.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tree), os.environ.get('PYTHONPATH', '')]).rstrip(os.pathsep))
    code = 'import sys; from tissue_sim_ros.cli import main; sys.exit(main())'
    done = subprocess.run([sys.executable, '-c', code, 'node-bench', *bench_args, '--out', str(run_dir)],
                          env=env, cwd=run_dir, capture_output=True, text=True)
    (run_dir / 'console.txt').write_text(done.stdout + done.stderr)
    if done.returncode != 0 or not result_file.is_file():
        raise PairedBenchError(f'node-bench of {tree} failed (exit {done.returncode}); its output: '
                           f'{run_dir / "console.txt"}')
    return json.loads(result_file.read_text())


def _check_plan(path: Path, plan: dict) -> None:
    """Resume only the same comparison: the plan of the runs already in DIR must be this one."""
    if path.is_file():
        earlier = json.loads(path.read_text())
        changed = [k for k in plan if earlier.get(k) != plan[k]]
        if changed:
            raise PairedBenchError(f'{path.parent} holds runs with another {", ".join(changed)} '
                                   f'({", ".join(repr(earlier.get(k)) for k in changed)}); expected an empty '
                                   'directory or the same comparison')
    else:
        path.write_text(json.dumps(plan, indent=2))


def summarise(rows: list[dict]) -> dict:
    """Per pair the after/before ratio of the node's CPU; their median, range and mean, and the
    ratio of the mean CPUs. ``rows``: dicts with 'pair', 'version' ('before'/'after') and
    'node_cpu_pct_of_one_core'."""
    cpu = {(r['pair'], r['version']): r['node_cpu_pct_of_one_core'] for r in rows}
    pairs = sorted({p for p, _ in cpu if (p, 'before') in cpu and (p, 'after') in cpu})
    ratios = [cpu[p, 'after'] / cpu[p, 'before'] for p in pairs]
    before = [cpu[p, 'before'] for p in pairs]
    after = [cpu[p, 'after'] for p in pairs]
    if not pairs:
        raise ValueError('no complete pair of runs')
    return {'pairs': len(pairs), 'ratios': ratios, 'ratio_median': statistics.median(ratios),
            'ratio_min': min(ratios), 'ratio_max': max(ratios), 'ratio_mean': statistics.fmean(ratios),
            'cpu_before_mean_pct': statistics.fmean(before), 'cpu_after_mean_pct': statistics.fmean(after),
            'ratio_of_means': statistics.fmean(after) / statistics.fmean(before),
            'goal_ratio': CPU_GOAL_RATIO}


def _plot(rows: list[dict], summary: dict, path: Path, title: str) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 4))
    for version, colour in (('before', 'tab:grey'), ('after', 'tab:blue')):
        points = sorted((r['pair'], r['node_cpu_pct_of_one_core']) for r in rows if r['version'] == version)
        ax.plot([p + 1 for p, _ in points], [c for _, c in points], 'o-', color=colour, label=version)
    goal = CPU_GOAL_RATIO * summary['cpu_before_mean_pct']
    ax.axhline(goal, color='tab:red', ls='--', lw=1, label=f'{CPU_GOAL_RATIO:g} x mean before')
    ax.set_xlabel('pair')
    ax.set_ylabel('node CPU [% of one core]')
    ax.set_ylim(bottom=0)
    ax.set_xticks(range(1, summary['pairs'] + 1))
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run(against: str, out: str, pairs: int = 3, duration_s: float = 20.0, rate_hz: float = 100.0,
        load: int = 0, scene_file: str | None = None, stream=print) -> dict:
    """Alternate ``pairs`` pairs of node-bench runs of revision ``against`` and of this checkout;
    write the figures into ``out``; returns the summary."""
    out = Path(out)
    revision_tree = out / 'revision'
    commit = export_revision(against, revision_tree)
    scene = str(Path(scene_file).resolve()) if scene_file else str(revision_tree / 'config' / 'liver_sample.yaml')
    bench_args = ['--duration-s', f'{duration_s:g}', '--rate-hz', f'{rate_hz:g}', '--load', str(load),
                  '--scene-file', scene]
    _check_plan(out / 'plan.json', {'commit': commit, 'scene': scene, 'bench_args': bench_args})
    trees = {'before': revision_tree, 'after': _this_tree()}
    rows = []
    for pair in range(pairs):
        order = ('before', 'after') if pair % 2 == 0 else ('after', 'before')
        for version in order:
            result = _bench_once(trees[version], out / 'runs' / f'pair{pair + 1}_{version}', bench_args)
            row = {'pair': pair, 'version': version, 'first': version == order[0],
                   **{k: result.get(k, '') for k in COLUMNS}}
            rows.append(row)
            stream(f'pair {pair + 1}/{pairs} {version:<6} node CPU {row["node_cpu_pct_of_one_core"]:.0f} % '
                   f'of one core, wrench {row["wrench_rate_hz"]:.3f} Hz')
    summary = {'against': against, 'commit': commit, 'scene': scene, 'load': load, 'duration_s': duration_s,
               **summarise(rows)}
    with open(out / 'paired.csv', 'w', newline='') as f:
        writer = csv.DictWriter(f, fieldnames=['pair', 'version', 'first', *COLUMNS])
        writer.writeheader()
        writer.writerows({**r, 'pair': r['pair'] + 1} for r in rows)
    (out / 'paired.json').write_text(json.dumps(summary, indent=2))
    verdict = 'meets' if summary['ratio_of_means'] <= CPU_GOAL_RATIO else 'misses'
    lines = [
        f'# node-bench, this checkout against {against} ({commit[:10]}), paired',
        '',
        f'{summary["pairs"]} pairs of {duration_s:g} s runs, load {load}, scene `{scene}`; the first run of '
        'a pair alternates.',
        '',
        f'- node CPU, mean: before {summary["cpu_before_mean_pct"]:.1f} %, after '
        f'{summary["cpu_after_mean_pct"]:.1f} % of one core; ratio of the means '
        f'**{summary["ratio_of_means"]:.2f}** ({verdict} the goal of at most {CPU_GOAL_RATIO:g})',
        f'- ratio within each pair: median {summary["ratio_median"]:.2f}, range '
        f'{summary["ratio_min"]:.2f}-{summary["ratio_max"]:.2f} '
        f'({", ".join(f"{x:.2f}" for x in summary["ratios"])})',
        '',
        'Rows: paired.csv; runs and their console output: runs/; chart: paired.png.',
    ]
    (out / 'paired.md').write_text('\n'.join(lines) + '\n')
    _plot(rows, summary, out / 'paired.png', f'node CPU, this checkout against {against}, load {load}')
    stream('\n'.join(lines[2:7]).replace('**', ''))
    stream(f'wrote {out / "paired.csv"}, paired.json, paired.md, paired.png')
    return summary
