"""The evaluations log of a calibration (``evaluations.jsonl`` in its ``--out DIR``): one JSON line
per evaluation as it ran, each evaluation once across resumes, and what the report counts from it.

A line: ``time``, ``values`` (the fitted keys), ``phases`` (a stage's scope, null for a whole
evaluation), ``objective`` and ``nrmse_mean`` (whole evaluations) or ``stage_objective`` (a
stage's), ``failures``, ``mass_scaling``, ``run`` (1 for the first run of a study, one more per
resume), ``elapsed_s`` (since that run started) and ``replayed`` (every simulation from an earlier
run's store), and with ``calibrate --per-repeat`` ``draws`` (which set of each repeat's offsets it
ran with: the same parameters under other offsets are another evaluation). A line cut by a kill
is skipped when read back.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

__all__ = ['log_evaluation', 'logged_keys', 'logged_runs']


def log_evaluation(path: Path, logged: set, evaluation, stage, *, run: int, elapsed_s: float) -> None:
    """Append ``evaluation`` to the log at ``path`` unless ``logged`` (the keys already there)
    holds it; ``stage``: a partial evaluation's stage residuals (None: a whole one)."""
    phases = None if evaluation.phases is None else str(evaluation.phases)
    key = _log_key(evaluation.values, phases, evaluation.draws)
    if key in logged:
        return
    logged.add(key)
    record = {'time': time.strftime('%Y-%m-%dT%H:%M:%S'), 'values': evaluation.values, 'phases': phases,
              'objective': evaluation.objective if stage is None else None,
              'stage_objective': None if stage is None else float(stage @ stage),
              'nrmse_mean': evaluation.nrmse_mean if stage is None else None,
              'failures': evaluation.failures,
              'mass_scaling': max((r.mass_scaling for r in evaluation.results), default=float('nan')),
              'run': run, 'elapsed_s': elapsed_s, 'replayed': bool(evaluation.replayed)}
    if evaluation.draws:
        record['draws'] = evaluation.draws
    with path.open('a') as log:
        log.write(json.dumps(record, default=float) + '\n')


def _log_key(values: dict, phases, draws: int = 0) -> str:
    return json.dumps([values, phases] + ([draws] if draws else []), sort_keys=True, default=float)


def logged_keys(path) -> tuple[set, int]:
    """The evaluations an earlier run of the study logged (a line cut by a kill is skipped), and
    this run's number (one more than the last logged)."""
    keys, last = set(), 0
    if path is None or not path.exists():
        return keys, 1
    text = path.read_text()
    if text and not text.endswith('\n'):
        with path.open('a') as log:                      # the next record starts on its own line
            log.write('\n')
    for line in text.splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue
        keys.add(_log_key(record.get('values'), record.get('phases'), record.get('draws', 0)))
        last = max(last, int(record.get('run') or 1))
    return keys, last + 1


def logged_runs(path) -> dict:
    """Per run of a study (its number): the evaluations it logged and its last ``elapsed_s``
    (the wall time it ran, to its last evaluation): what the report counts across resumes."""
    runs: dict = {}
    if path is None or not Path(path).exists():
        return runs
    for line in Path(path).read_text().splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue
        run = runs.setdefault(int(record.get('run') or 1), {'evaluations': 0, 'elapsed_s': 0.0})
        run['evaluations'] += 1
        run['elapsed_s'] = max(run['elapsed_s'], float(record.get('elapsed_s') or 0.0))
    return runs
