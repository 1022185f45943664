"""tissue-sim stability (analysis/charting/stability.py): the measured largest stable step against the
solver's estimate, every induced failure caught or survived with no NaN, and the outputs and
resume of the command."""

import csv
import json

import numpy as np
import pytest

from tissue_sim_ros.analysis.charting import stability


def _job(**selection):
    return stability.jobs_for(None, [], quick=True, speed=0.005, **selection)


def test_explicit_bisection_brackets_the_estimate():
    """The linear model on the coarse scene: the search finds the step where the run stops being
    stable, and it is within 25 % of the Lanczos estimate of 2 / omega_max (the goal); the trials
    bracket it (stable at the result, unstable at the next trial above it)."""
    job, = _job(models=('linear',), integrators=('explicit',), cases=())
    row = stability.bisect_job(job)
    assert not row['limit_reached']
    assert 0.75 <= row['ratio'] <= 1.25
    stable = [f for f, ok in row['trials'] if ok]
    unstable = [f for f, ok in row['trials'] if not ok]
    assert max(stable) == pytest.approx(row['ratio'])
    assert min(unstable) > row['ratio']
    assert min(unstable) / row['ratio'] < 1.1          # 5 halvings of log(8): within 7 %


def test_implicit_stable_far_past_the_explicit_estimate():
    job, = _job(models=('full',), integrators=('implicit',), cases=())
    row = stability.bisect_job(job)
    assert row['ratio'] >= 16.0


@pytest.mark.parametrize('case', stability.FAILURE_CASES)
def test_induced_failure_caught_or_survived_never_nan(case):
    job, = _job(models=(), integrators=(), cases=(case,))
    row = stability.failure_job(job)
    assert row['outcome'] in ('caught', 'survived', 'refused'), row
    if case in ('step_2x', 'step_4x'):           # past the limit: caught, named, within 5 steps
        assert row['outcome'] == 'caught'
        assert 'energy grew without input' in row['reason']
        assert 0 <= row['steps_to_detect'] <= 5
    if case == 'sliver_elements':
        assert 'smallest mean ratio at rest 0.0' in row['detail']


def test_command_outputs_and_resume(tmp_path):
    selection = dict(models=('linear',), integrators=('explicit',), cases=('step_4x',))
    report = stability.run_stability(quick=True, out=tmp_path, workers=1, quiet=True, **selection)
    for name in ('stability.csv', 'failures.csv', 'stability.png', 'stability.md', 'stability.json'):
        assert (tmp_path / name).stat().st_size > 0
    rows = list(csv.DictReader((tmp_path / 'stability.csv').open()))
    assert [r['model'] for r in rows] == ['linear']
    assert float(rows[0]['measured_max_dt_s']) == pytest.approx(report['stability'][0]['measured_max_dt_s'])
    assert list(csv.DictReader((tmp_path / 'failures.csv').open()))[0]['outcome'] == 'caught'
    log = tmp_path / 'runs.jsonl'
    lines = log.read_text().splitlines()
    assert len(lines) == 2
    log.write_text(lines[0] + '\n' + lines[1][:20])       # an interrupted write: a cut last line
    again = stability.run_stability(quick=True, out=tmp_path, workers=1, quiet=True, **selection)
    assert len(log.read_text().splitlines()) == 3           # only the cut job ran again, on its own line
    assert again['stability'] == report['stability']
    assert json.loads((tmp_path / 'stability.json').read_text())['failures'][0]['case'] == 'step_4x'
    assert np.isfinite(again['failures'][0]['steps_to_detect'])
