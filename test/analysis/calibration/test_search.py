"""The calibration's global stage (analysis/calibration/search.py) on a linear problem whose optimum
numpy's least squares gives: it starts from the start and ends far closer to the optimum."""

import numpy as np
import pytest

from support.calibration import _LinearObjective
from tissue_sim_ros.analysis.calibration.objective import Objective
from tissue_sim_ros.analysis.calibration.parameters import parse_fit


@pytest.mark.parametrize('method', ['de', 'optuna'])
def test_the_global_stage_starts_from_the_start_and_gets_far_closer_to_the_optimum(method):
    """Either global method (scipy's differential evolution, Optuna's TPE) over a least-squares
    problem whose start is far off: the start is among what it tries, and what it returns scores
    a small fraction of the start's objective, nearer numpy's optimum."""
    pytest.importorskip(method if method == 'optuna' else 'scipy')
    from tissue_sim_ros.analysis.calibration.search import GLOBAL_METHODS
    rng = np.random.default_rng(7)
    A = rng.normal(size=(40, 3))
    b = A @ np.array([0.3, 0.7, 0.5]) + 0.01 * rng.normal(size=40)
    objective = _LinearObjective(A, b, [parse_fit(f'a{i}=0:1') for i in range(3)])
    start = np.array([0.95, 0.05, 0.95])
    u = GLOBAL_METHODS[method](objective, start, 5, 0)
    optimum = np.linalg.lstsq(A, b, rcond=None)[0]
    print(f'{method}: {len(objective.evaluations)} evaluations, objective {objective.evaluate(start).objective:.3g} '
          f'-> {objective.evaluate(u).objective:.3g}; distance to the optimum {np.max(np.abs(u - optimum)):.3f}')
    assert Objective._key(start) in objective._cache
    assert objective.evaluate(u).objective < 0.1 * objective.evaluate(start).objective
    assert np.max(np.abs(u - optimum)) < 0.5 * np.max(np.abs(start - optimum))


# A layered problem with a known answer for the staged search's two ends: a start already at the
# optimum ends at once and says so; a poor start improves in every stage. Residuals linear in the
# keys, one block per part of a two-layer curve (the labels analysis.calibration.stages gives its
# samples), each block moved only by the keys that act there (a layer's loading and puncture keys
# on its segment, its cutting force on the next, the retraction key on the retraction, the
# relaxation on the hold). Its optimum is numpy's least squares over every block at once.
REGIONS = [{'name': 'outer', 'membrane': {'criterion': 'force'}}, {'name': 'deep', 'membrane': {'criterion': 'force'}}]
KEYS = ['regions[0].young_modulus_pa=1e4:1e5', 'regions[0].membrane.rupture_force_n=1:6',
        'regions[0].cutting_force_n=0:1', 'regions[1].young_modulus_pa=1e4:1e5',
        'regions[1].membrane.rupture_force_n=1:6', 'regions[1].cutting_force_n=0:1',
        'regions[1].friction.retraction_constant_n=0:3', 'model.relaxation[0].relative_modulus=0.05:0.95']
#: each label's block: the keys (indices into KEYS) that move its samples
BLOCKS = {'segment 0': (0, 1), 'segment 1': (0, 2, 3, 4), 'segment 2': (2, 5), 'retraction 0': (6,),
          'retraction 1': (6,), 'hold': (7, 3)}


class LayeredLinearObjective(_LinearObjective):
    """r(u) = A u - b, A's rows in blocks by label (``BLOCKS``), with the objective interface the
    search uses (staged stages pick their labels' rows)."""

    def __init__(self, b_noise=0.0, seed=0, rows=12):
        rng = np.random.default_rng(seed)
        keys = [parse_fit(text) for text in KEYS]
        self.regions, self.n_layers = REGIONS, 2
        self.labels = np.repeat(list(BLOCKS), rows)
        A = np.zeros((len(self.labels), len(keys)))
        for label, acting in BLOCKS.items():
            rows_of = self.labels == label
            A[np.ix_(rows_of, acting)] = rng.normal(size=(rows, len(acting)))
        self.optimum_u = rng.uniform(0.2, 0.8, size=len(keys))
        b = A @ self.optimum_u + b_noise * rng.normal(size=len(self.labels))
        self.least_squares_u = np.linalg.lstsq(A, b, rcond=None)[0]
        super().__init__(A, b, keys)

    def values(self, u):
        return {k.key: k.value(x) for k, x in zip(self.keys, u)}

    def stage_residuals(self, evaluation, phases=None):
        if phases is None:
            return evaluation.residuals
        return evaluation.residuals[np.isin(self.labels, phases.labels)]


def test_a_start_already_at_the_optimum_ends_at_once_and_says_so():
    """At the least-squares optimum with the fit within the noise floor: one evaluation and one
    Jacobian (1 + 8 evaluations), no stage run, the log and the record say why; the same start
    judged not yet within the noise floor searches on."""
    from tissue_sim_ros.analysis.calibration.search import search
    objective = LayeredLinearObjective(b_noise=0.01)
    said, record = [], []
    u = search(objective, objective.least_squares_u, enough=lambda e: True, log=said.append, record=record)
    np.testing.assert_allclose(u, objective.least_squares_u, atol=1e-12)
    assert len(objective.evaluations) == 1 + len(KEYS)
    assert [entry['stage'] for entry in record] == ['start'] and record[0]['stopped'] == 'already optimal'
    assert record[0]['predicted_gain'] < 1e-9
    assert any('already optimal' in line and 'the search ends here' in line for line in said)
    searching = LayeredLinearObjective(b_noise=0.01)
    search(searching, searching.least_squares_u, enough=lambda e: False, log=lambda text: None,
           stage_evaluations=4, joint_evaluations=4)
    assert len(searching.evaluations) > 1 + len(KEYS)


def test_a_poor_start_improves_in_every_stage_and_ends_near_the_optimum():
    """From every key at 0.05 (the optimum's keys lie in 0.2-0.8): each stage of the plan (the
    loading and puncture of each layer, after each puncture, the retraction, the pause) lowers its
    own residuals' objective (the whole one may rise a little when a stage's key also acts beyond
    its samples: a cutting force on the next segment too); the staged start as a whole takes off
    most of the objective, and the result lies within 0.02 of the least-squares optimum in every
    key."""
    from tissue_sim_ros.analysis.calibration.search import search
    objective = LayeredLinearObjective(b_noise=0.01, seed=3)
    record = []
    u = search(objective, np.full(len(KEYS), 0.05), log=lambda text: None, record=record, stage_evaluations=20,
               joint_evaluations=30)
    stages = [entry for entry in record if 'objective_before' in entry]
    assert [entry['stage'] for entry in stages] == ['layer 0', 'after puncture 0', 'layer 1', 'after puncture 1',
                                                    'retraction', 'pause']
    for entry in stages:
        assert entry['objective_after'] < 0.97 * entry['objective_before'], entry['stage']
    staged = next(entry for entry in record if entry['stage'] == 'staged start')
    assert staged['whole_after'] < 0.2 * staged['whole_before']
    np.testing.assert_allclose(u, objective.least_squares_u, atol=0.02)


class _ScoredLinearObjective(_LinearObjective):
    """The linear model with its residuals in ``trials`` equal blocks, one per trial: each
    evaluation's trial sizes, and its NRMSE per trial (the block's RMS) as a simulation's
    comparisons carry it."""

    trials = 6

    def evaluate_many(self, us, phases=None):
        from types import SimpleNamespace
        out = super().evaluate_many(us, phases)
        for evaluation in out:
            blocks = np.array_split(evaluation.residuals, self.trials)
            evaluation.trial_sizes = tuple(len(b) for b in blocks)
            evaluation.comparisons[:] = [SimpleNamespace(errors={'nrmse': float(np.sqrt(np.mean(b ** 2)))})
                                         for b in blocks]
        return out


def _collinear_problem(epsilon, seed=11):
    """Residuals of three keys where the first two act almost alike (their columns differ by
    ``epsilon`` times noise; the data's noise as small, so the optimum stays inside the bounds),
    and numpy's least-squares optimum."""
    rng = np.random.default_rng(seed)
    column = rng.normal(size=60)
    A = np.stack([column, column + epsilon * rng.normal(size=60), rng.normal(size=60)], axis=1)
    b = A @ np.array([0.4, 0.5, 0.6]) + 1e-3 * rng.normal(size=60)
    keys = [parse_fit(f'a{i}=0:1') for i in range(3)]
    return _ScoredLinearObjective(A, b, keys), np.linalg.lstsq(A, b, rcond=None)[0]


def test_the_least_determined_combination_is_the_pair_that_acts_alike_and_the_data_cannot_tell_it():
    """Two keys whose columns nearly coincide trade one for the other: the probe steps them in
    opposite directions by WEAK_REACH and leaves the third key (determined on its own) out; the
    fit at both ends is within 1 % of the optimum's, and the six trials do not agree that an end
    fits worse (their parts of the objective), so the data cannot tell them apart."""
    from tissue_sim_ros.analysis.calibration.search import TOLD_APART_T, WEAK_REACH, jacobian, weakest_direction
    objective, optimum = _collinear_problem(epsilon=1e-3)
    J = jacobian(objective, optimum, [0, 1, 2])
    fit = float(np.sqrt(np.mean(objective.residuals(optimum) ** 2)))
    probe = weakest_direction(objective, optimum, J, noise_floor=float('nan'))
    print(probe)
    assert set(probe['keys']) == {'a0', 'a1'}
    steps = [probe['keys'][k]['plus'] - probe['keys'][k]['value'] for k in ('a0', 'a1')]
    assert steps[0] * steps[1] < 0 and max(abs(s) for s in steps) == pytest.approx(WEAK_REACH, rel=1e-9)
    assert abs(abs(steps[0]) - abs(steps[1])) < 0.01 * WEAK_REACH
    low, at, high = probe['nrmse']
    assert max(low, high) < at * 1.01
    assert min(probe['worse_t']) < TOLD_APART_T
    assert probe['told_apart'] is False


def test_keys_the_data_determines_are_told_apart():
    """Three keys with independent columns: the least-determined step raises every trial's fit
    above its optimum (by the Gauss-Newton model's amount: the residuals are linear), so the
    trials agree that both ends fit worse and the data tells the keys apart; with one trial
    there are no repeats to judge by."""
    from tissue_sim_ros.analysis.calibration.search import TOLD_APART_T, jacobian, weakest_direction
    objective, optimum = _collinear_problem(epsilon=1.0)
    J = jacobian(objective, optimum, [0, 1, 2])
    probe = weakest_direction(objective, optimum, J, noise_floor=float('nan'))
    step = np.array([probe['keys'][k]['plus'] - probe['keys'][k]['value'] if k in probe['keys'] else 0.0
                     for k in ('a0', 'a1', 'a2')])
    moved = np.array_split(objective.residuals(optimum) + objective.A @ step, objective.trials)
    assert probe['nrmse'][2] == pytest.approx(np.mean([np.sqrt(np.mean(b ** 2)) for b in moved]), rel=1e-9)
    assert probe['objective'][2] == pytest.approx(sum(float(b @ b) for b in moved), rel=1e-9)
    assert min(probe['worse_t']) >= TOLD_APART_T
    assert probe['told_apart'] is True
    single, optimum = _collinear_problem(epsilon=1.0)
    single.trials = 1
    assert weakest_direction(single, optimum, J, noise_floor=float('nan'))['told_apart'] is None


def test_the_report_gives_the_probe_its_verdict_and_no_statistic_without_repeats():
    """The report's words for the probe: each key's range, the fits, and the paired statistic
    only where there were repeats to pair (one trial: no verdict, no statistic)."""
    from tissue_sim_ros.analysis.calibration.report import _weakest_text
    probe = {'keys': {'a0': {'value': 0.5, 'minus': 0.4, 'plus': 0.6}}, 'nrmse': [0.03, 0.02, 0.03],
             'objective': [0.002, 0.001, 0.002], 'worse_t': [3.0, 2.5], 'noise_floor': 0.05, 'told_apart': True}
    text = _weakest_text(probe)
    assert 'a0 0.4 to 0.6 (-20 % to +20 %)' in text and 'worse by 3.0 and 2.5 standard errors' in text
    alone = _weakest_text(dict(probe, worse_t=[float('nan')] * 2, told_apart=None))
    assert 'nan' not in alone and 'standard errors' not in alone


def test_a_key_whose_optimum_lies_past_its_bound_is_reported_pushed_past_it_moved_or_not():
    """Two keys, the least-squares optimum of the first at 1.4 in unit coordinates, beyond its
    bound at 1: the search stops it there; it moved, and the report says it ended at its upper
    bound with the fit pushing past it (warned: the other key makes up for it). The second key,
    inside its bounds, is not. Truth: numpy's unbounded least squares."""
    from tissue_sim_ros.analysis.calibration.report import _moved_text
    from tissue_sim_ros.analysis.calibration.search import uncertainty, why_not_moved
    rng = np.random.default_rng(3)
    A = rng.normal(size=(30, 2))
    b = A @ np.array([1.4, 0.5])
    objective = _LinearObjective(A, b, [parse_fit(f'a{i}=0:1') for i in range(2)])
    assert np.linalg.lstsq(A, b, rcond=None)[0][0] == pytest.approx(1.4)
    u0 = np.array([0.5, 0.5])
    u = np.array([1.0, 0.5 + np.linalg.lstsq(A[:, 1:], b - A[:, 0], rcond=None)[0][0]])   # the bounded optimum
    spread = uncertainty(objective, u)
    moved = why_not_moved(objective, u0, u, spread['jacobian_matrix'], spread['correlation'])
    assert moved['a0']['moved'] and moved['a0']['pushed_past'] == 'upper'
    assert moved['a1']['pushed_past'] is None
    assert _moved_text({'moved': True, 'pushed_past': 'upper'}) == 'yes, to its upper bound'
    still = why_not_moved(objective, u, u, spread['jacobian_matrix'], spread['correlation'])
    assert not still['a0']['moved'] and still['a0']['pushed_past'] == 'upper' and 'upper bound' in still['a0']['why']
