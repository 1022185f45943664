"""``tissue-sim node-bench --against REV --out DIR``: this checkout's node against an earlier
revision's, on one scene, in alternating runs, for a before/after figure on a shared machine.

Why paired: on a shared 2-core VM the same node's CPU moves between 48 % and 75 % of a core within
half an hour (other tenants); one run of each, taken at different times, cannot show a change of a
third. Each pair runs both versions back to back, the first of the two alternating
from pair to pair, and the figures are the ratio within each pair (median and range) and the
ratio of the mean CPUs.

The earlier revision is exported with ``git archive`` into DIR/revision and run from there (first
on PYTHONPATH; each run checks that it imported the package from there) in this same virtual
environment, so its dependencies must still be installed; its caches (numba's kernels, the
ladder's errors) go to DIR/cache, apart from this checkout's. Each version runs its own
``tissue-sim node-bench``. Both run the same scene: by default the earlier revision's packaged
one, which the older engine is sure to read. With ``--against-scene SCENE`` instead of
``--against``, this checkout runs on SCENE (before) and on ``--scene`` (after): what a scene's
option costs the node, paired the same way. Each run keeps its ``node_bench.json`` and console
output in DIR/runs/; a run already there is reused (resume) when DIR/plan.json says it belongs
to the same comparison: the revision, this checkout (its commit and uncommitted changes), the
scene's text and the bench's options. Writes paired.csv (one row per run), paired.json,
paired.md and paired.png.
"""
from __future__ import annotations

import csv
import hashlib
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
from tissue_sim_ros.system.child_env import importing_from
from tissue_sim_ros.errors import BenchError

__all__ = ['run', 'summarise', 'resolve_commit', 'export_revision', 'BenchError']

#: figures kept per run (node_bench.json keys both versions write; the kernel share only newer
#: ones). Each side measures with its own node-bench, so a figure whose method differs between
#: the two revisions (the latency) is not comparable across them.
COLUMNS = ('node_cpu_pct_of_one_core', 'kernel_share_of_node_cpu', 'wrench_rate_hz',
           'tick_period_dev_ms_p99', 'latency_ms_p99', 'missed_ticks', 'ticks')
CPU_GOAL_RATIO = 0.6   # the goal: this checkout's node CPU at most 0.6 of the revision's


def _this_tree() -> Path:
    return Path(tissue_sim_ros.__file__).resolve().parents[1]


def _git(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(['git', '-C', str(_this_tree()), *args], capture_output=True)


def resolve_commit(rev: str) -> str:
    """The full hash of commit ``rev`` of this checkout's repository; BenchError when this
    is not a git checkout or ``rev`` names no commit."""
    found = _git('rev-parse', '--verify', '--quiet', f'{rev}^{{commit}}')
    if found.returncode != 0:
        raise BenchError(f'--against {rev!r}: no such commit in {_this_tree()} (a git checkout is needed)')
    return found.stdout.decode().strip()


def _this_checkout() -> str:
    """This checkout's commit and a hash of its uncommitted changes to tracked files."""
    head = _git('rev-parse', 'HEAD').stdout.decode().strip()
    changes = _git('diff', 'HEAD').stdout
    return f'{head}+{hashlib.sha256(changes).hexdigest()[:12]}' if changes else head


def export_revision(commit: str, into: Path) -> None:
    """Write the files of ``commit`` into ``into`` (kept when they are that commit's already)."""
    if (into / 'COMMIT').is_file() and (into / 'COMMIT').read_text().strip() == commit:
        return
    if into.exists():
        shutil.rmtree(into)      # another revision's files: none of them may stay
    into.mkdir(parents=True)
    archive = _git('archive', '--format=tar', commit)
    if archive.returncode != 0:
        raise BenchError(f'git archive {commit}: {archive.stderr.decode().strip()}')
    with tarfile.open(fileobj=io.BytesIO(archive.stdout)) as tar:
        tar.extractall(into, filter='data')
    (into / 'COMMIT').write_text(commit + '\n')


# the child's first lines: tissue_sim_ros must come from the tree it was pointed at
_CHILD = """import pathlib, sys
import tissue_sim_ros
tree, package = pathlib.Path(sys.argv.pop(1)).resolve(), pathlib.Path(tissue_sim_ros.__file__).resolve()
if not package.is_relative_to(tree):
    sys.exit(f'imported tissue_sim_ros from {package}, not from {tree}')
from tissue_sim_ros.cli import main
sys.exit(main())
"""


def _bench_once(tree: Path, run_dir: Path, bench_args: list[str], env: dict) -> tuple[dict, bool]:
    """One ``tissue-sim node-bench`` of the package in ``tree``: its node_bench.json, and whether
    it was there already."""
    result_file = run_dir / 'node_bench.json'
    reused = result_file.is_file()
    if not reused:
        run_dir.mkdir(parents=True, exist_ok=True)
        done = subprocess.run([sys.executable, '-c', _CHILD, str(tree), 'node-bench', *bench_args,
                               '--out', str(run_dir)], env=importing_from(tree, env), cwd=run_dir,
                              capture_output=True, text=True)
        (run_dir / 'console.txt').write_text(done.stdout + done.stderr)
        if done.returncode != 0 or not result_file.is_file():
            raise BenchError(f'node-bench of {tree} failed (exit {done.returncode}); its output: '
                                   f'{run_dir / "console.txt"}')
    result = json.loads(result_file.read_text())
    if result.get('node_exit_code') != 0 or not isinstance(result.get('node_cpu_pct_of_one_core'), (int, float)):
        raise BenchError(f'{result_file}: the node exited with {result.get("node_exit_code")!r} or its CPU '
                               'was not measured; delete that run to measure it again')
    return result, reused


def _check_plan(out: Path, plan: dict) -> None:
    """Resume only the same comparison: runs already in ``out`` must have been made under this
    plan; without runs the plan is (re)written."""
    path = out / 'plan.json'
    if any((out / 'runs').glob('*/node_bench.json')):
        if not path.is_file():
            raise BenchError(f'{out} holds runs but no plan.json saying what they compare; expected '
                                   'an empty directory or one this command filled')
        earlier = json.loads(path.read_text())
        changed = [k for k in plan if earlier.get(k) != plan[k]]
        if changed:
            raise BenchError(f'{out} holds runs with another {", ".join(changed)} '
                                   f'({", ".join(repr(earlier.get(k)) for k in changed)}); expected an empty '
                                   'directory or the same comparison')
        return
    out.mkdir(parents=True, exist_ok=True)
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


def _plan_revision(against, out, bench_args, scene_file):
    """(trees, scenes, environments, commit) of a comparison with revision ``against``."""
    revision_tree = out / 'revision'
    commit = resolve_commit(against)
    scene = str(Path(scene_file).resolve()) if scene_file else None
    scene_text = Path(scene).read_bytes() if scene else _git('show', f'{commit}:config/liver_sample.yaml').stdout
    plan = {'commit': commit, 'this_checkout': _this_checkout(), 'bench_args': bench_args,
            'scene': scene or 'the revision\'s config/liver_sample.yaml',
            'scene_sha256': hashlib.sha256(scene_text).hexdigest()}
    _check_plan(out, plan)
    export_revision(commit, revision_tree)
    scene = scene or str(revision_tree / 'config' / 'liver_sample.yaml')
    return ({'before': revision_tree, 'after': _this_tree()}, {'before': scene, 'after': scene},
            {'before': dict(os.environ, XDG_CACHE_HOME=str(out / 'cache')), 'after': dict(os.environ)}, commit)


def _plan_scenes(against_scene, out, bench_args, scene_file):
    """(trees, scenes, environments, commit) of this checkout on ``scene_file`` (after) against
    itself on ``against_scene`` (before)."""
    scenes = {'before': str(Path(against_scene).resolve()),
              'after': str(Path(scene_file or _this_tree() / 'config' / 'liver_sample.yaml').resolve())}
    for version, scene in scenes.items():
        if not Path(scene).is_file():
            raise BenchError(f'{"--against-scene" if version == "before" else "--scene"} {scene!r}: no such file')
    this = _this_checkout()
    _check_plan(out, {'this_checkout': this, 'bench_args': bench_args, 'scene': scenes['after'],
                      'against_scene': scenes['before'],
                      **{f'{v}_scene_sha256': hashlib.sha256(Path(s).read_bytes()).hexdigest()
                         for v, s in scenes.items()}})
    return {'before': _this_tree(), 'after': _this_tree()}, scenes, {'before': dict(os.environ),
                                                                     'after': dict(os.environ)}, this


def run(against: str | None, out: str, pairs: int = 3, duration_s: float = 20.0, rate_hz: float = 100.0,
        load: int = 0, scene_file: str | None = None, stream=print, against_scene: str | None = None) -> dict:
    """Alternate ``pairs`` pairs of node-bench runs of revision ``against`` and of this checkout
    (or, with ``against_scene``, of this checkout on that scene and on ``scene_file``: the cost of
    a scene's option, a flexible needle's rod say); write the figures into ``out``; returns the
    summary."""
    out = Path(out).resolve()
    bench_args = ['--duration-s', repr(float(duration_s)), '--rate-hz', repr(float(rate_hz)), '--load', str(load)]
    if (against is None) == (against_scene is None):
        raise BenchError('expected one of --against REV and --against-scene SCENE')
    if against_scene is not None:
        trees, scenes, envs, commit = _plan_scenes(against_scene, out, bench_args, scene_file)
        against = f'scene {scenes["before"]}'
    else:
        trees, scenes, envs, commit = _plan_revision(against, out, bench_args, scene_file)
    scene = scenes['after']
    rows = []
    for pair in range(pairs):
        order = ('before', 'after') if pair % 2 == 0 else ('after', 'before')
        for version in order:
            result, reused = _bench_once(trees[version], out / 'runs' / f'pair{pair + 1}_{version}',
                                         bench_args + ['--scene-file', scenes[version]], envs[version])
            row = {'pair': pair, 'version': version, 'first': version == order[0],
                   **{k: result.get(k, '') for k in COLUMNS}}
            rows.append(row)
            stream(f'pair {pair + 1}/{pairs} {version:<6} node CPU {row["node_cpu_pct_of_one_core"]:.0f} % '
                   f'of one core, wrench {result.get("wrench_rate_hz", float("nan")):.3f} Hz'
                   + (' (reused)' if reused else ''))
    summary = {'against': against, 'commit': commit, 'scene': scene, 'load': load, 'duration_s': duration_s,
               **summarise(rows)}
    with open(out / 'paired.csv', 'w', newline='') as f:
        writer = csv.DictWriter(f, fieldnames=['pair', 'version', 'first', *COLUMNS])
        writer.writeheader()
        writer.writerows({**r, 'pair': r['pair'] + 1} for r in rows)
    (out / 'paired.json').write_text(json.dumps(summary, indent=2))
    # the goal is a revision's (the node's CPU cut); a scene's option has a cost, not a goal
    goal = '' if against.startswith('scene ') else (
        f" ({'meets' if summary['ratio_of_means'] <= CPU_GOAL_RATIO else 'misses'} the goal of at most "
        f'{CPU_GOAL_RATIO:g})')
    lines = [
        f'# node-bench, this checkout against {against} ({commit[:10]}), paired',
        '',
        f'{summary["pairs"]} pairs of {duration_s:g} s runs, load {load}, scene `{scene}`; the first run of '
        'a pair alternates.',
        '',
        f'- node CPU, mean: before {summary["cpu_before_mean_pct"]:.1f} %, after '
        f'{summary["cpu_after_mean_pct"]:.1f} % of one core; ratio of the means '
        f'**{summary["ratio_of_means"]:.2f}**{goal}',
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
