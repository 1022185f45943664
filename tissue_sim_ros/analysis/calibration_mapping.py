"""Coarse to fine: search the cheap scene corrected to agree with the scene as asked where that
was last run (output space mapping), then finish on the scene as asked with its own Jacobian.

A coarser mesh is not the same tissue: it is stiffer, its contact patch is coarser, its puncture
comes at another depth, so the optimum found on it is not the fine scene's (on the calibration
benchmark the coarse optimum, 0.016 NRMSE there, scored 0.090 on the fine scene). Output space
mapping (Bandler et al., IEEE Trans. MTT 52(1), 2004, section IV; Koziel, Bandler & Madsen 2006)
keeps the cheap scene for the search and removes its bias: with r_f and r_c the fine and coarse
residual vectors (the same data samples),

    s_k(u) = r_c(u) + (r_f(u_k) - r_c(u_k)),

which equals the fine residuals at u_k; the next point u_{k+1} minimises |s_k|^2 (a bounded
least-squares refinement on the coarse scene), the fine scene is run once there, and the
correction is renewed. Each iteration costs one fine evaluation; it stops when the fine objective
no longer falls, or before that evaluation when the point no longer moves or the corrected scene
predicts less than ``MIN_PREDICTED_GAIN`` of improvement. The Jacobian of s_k is the coarse one
whatever the shift, so after the first iteration (a full refinement, Jacobians taken as it goes)
the coarse Jacobian is taken once at each accepted point and the next refinement takes chord
steps with it (``CHORD_EVALUATIONS`` coarse runs, not a Jacobian's batch per step): with r
linear the iterations then converge to the u where J_c^T r_f(u) = 0, as the full refinements
would (the method's own fixed point). Without the finish below, the standard errors at the
optimum come from the coarse scene's Jacobian there (the last one taken) around the fine residuals.

The mapping's fixed point is not the fine optimum when the coarse scene responds to the keys
along other directions, and a coarse mesh does: on the calibration benchmark its Jacobian differs
from the fine one by 36-141 % per key (the exponential law acts on the strain near the needle,
which a coarse mesh smears), the iterations stopped at NRMSE 0.0446 where the true keys score
0.0054, and manifold mapping (the correction's Jacobian from the fine runs made, Echeverria &
Hemker 2008) did no better there (0.046: its secants span moves too long for that non-linear
response). So the mapping is followed by a **fine finish** (:func:`fine_finish`): the fine
scene's own Jacobian at the mapped point (one parallel batch; forward differences of
``FINISH_FD_STEP``), then Gauss-Newton steps on the
fine scene, each the bounded linear least-squares step (scipy lsq_linear) within a box of
``FINISH_RADIUS`` (halved after a step that does not lower the objective), the Jacobian updated
after each by Broyden's rank-one secant rule so that no further batch is spent. Chord steps
with the Jacobian held converged linearly there (on the small synthetic study, stiffness -13 %,
-8 %, -4 % after one, two, three; with the updates -3 % and +1 % after two and three). The
first Jacobian gives the standard errors: the fine scene's, not the coarse one's, though taken
where the finish started, not at the point it returns (another batch would cost as much again;
the report says so).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

__all__ = ['CorrectedObjective', 'broyden_update', 'fine_finish', 'linear_model_warning', 'space_mapping']

#: a point that moved less than this (unit coordinates, every key) ends the iterations
MOVE_TOLERANCE = 1e-3
#: so does a corrected optimum predicted to lower the objective by less than this fraction: the
#: fine evaluation it would cost buys less than the noise between the two scenes' predictions
MIN_PREDICTED_GAIN = 0.1
#: the fine finish's forward-difference step in unit coordinates. While the objective scored the
#: samples between a simulated and a measured puncture, it was a staircase on small scales and a
#: step of 0.1 read it best (at the benchmark's mapped point 0.01, 0.03 and 0.1 predicted 0.0095,
#: 0.0038 and 0.0011 at the true values, actual 0.00003). With the puncture's shift a smooth
#: residual (:mod:`~tissue_sim_ros.analysis.calibration_objective`) the search's own step is the
#: better one: four finish steps from that point ended at 5.3e-5 with 0.03 and 1.2e-4 with 0.1
#: (the true values 5.1e-5)
FINISH_FD_STEP = 0.03
#: the fine finish's largest step in any unit coordinate (halved at a step that does not improve)
FINISH_RADIUS = 0.25
#: a finish step whose gain differs from its linear model's prediction by more than this factor
#: is reported (:func:`linear_model_warning`)
LINEAR_MODEL_FACTOR = 3.0
#: coarse evaluations of each refinement after the first (chord steps with the Jacobian taken
#: where the last iteration landed)
CHORD_EVALUATIONS = 4


class CorrectedObjective:
    """The coarse objective plus a fixed residual shift (the search's objective interface)."""

    def __init__(self, coarse, shift: np.ndarray):
        self.coarse, self.keys, self.shift = coarse, coarse.keys, np.asarray(shift, dtype=float)
        self._cache: dict = {}
        self.best = None
        self.budget: int | None = None

    @property
    def evaluations(self) -> list:
        return list(self._cache.values())

    def evaluate_many(self, us) -> list:
        from tissue_sim_ros.analysis.calibration_objective import BudgetSpent
        keys = [self.coarse._key(u) for u in us]
        new = set(k for k in keys if k not in self._cache)
        if new and self.budget is not None and len(self._cache) + len(new) > self.budget:
            raise BudgetSpent(f'{self.budget} evaluations spent')
        for k, evaluation in zip(keys, self.coarse.evaluate_many(us)):
            if k not in self._cache:
                corrected = replace(evaluation, residuals=evaluation.residuals + self.shift)
                self._cache[k] = corrected
                if self.best is None or corrected.objective < self.best.objective:
                    self.best = corrected
        return [self._cache[k] for k in keys]

    def evaluate(self, u):
        return self.evaluate_many([u])[0]

    def stage_residuals(self, evaluation, phases=None) -> np.ndarray:
        if phases is not None:
            raise ValueError('the corrected objective fits every residual together (phases=None)')
        return evaluation.residuals


def space_mapping(fine, coarse, u, *, iterations: int, evaluations_per_iteration: int, log=print):
    """The best fine point from ``u`` after at most ``iterations`` fine evaluations, and the
    corrected objective at it (for the uncertainty); see the module docstring."""
    from tissue_sim_ros.analysis.calibration_search import jacobian, search
    u = np.asarray(u, dtype=float)
    best = fine.evaluate(u)
    corrected = CorrectedObjective(coarse, best.residuals - coarse.evaluate(u).residuals)
    chord = None
    for k in range(iterations):
        if k:   # the coarse Jacobian where the last iteration landed (taken here, not after the last)
            chord = jacobian(corrected, u, list(range(len(u))))
        budget = evaluations_per_iteration if chord is None else CHORD_EVALUATIONS
        candidate = search(corrected, u, staged=False, joint_evaluations=budget, max_evaluations=budget,
                           fixed_jacobian=chord, log=lambda text: None)
        predicted = corrected.evaluate(candidate).objective
        if np.max(np.abs(candidate - u)) < MOVE_TOLERANCE or predicted > (1.0 - MIN_PREDICTED_GAIN) * best.objective:
            log(f'space mapping {k + 1}: the corrected scene predicts {predicted:.5g} against '
                f'{best.objective:.5g} now; done')
            break
        trial = fine.evaluate(candidate)
        log(f'space mapping {k + 1}: fine objective {best.objective:.5g} -> {trial.objective:.5g} '
            f'(predicted {predicted:.5g})')
        if trial.objective >= best.objective:
            break
        u, best = candidate, trial
        corrected = CorrectedObjective(coarse, best.residuals - coarse.evaluate(u).residuals)
    return u, corrected


def broyden_update(B: np.ndarray, step: np.ndarray, change: np.ndarray) -> np.ndarray:
    """B + (change - B step) step^T / |step|^2 (Broyden, Math. Comp. 19, 1965): the Jacobian that
    maps ``step`` onto the residual ``change`` it caused, unchanged across directions orthogonal
    to the step."""
    return B + np.outer(change - B @ step, step) / float(step @ step)


def fine_finish(fine, u, *, steps: int, log=print):
    """At most ``steps`` Gauss-Newton steps (one fine evaluation each) on the fine scene from ``u``,
    starting with its own Jacobian there and updating it by Broyden's rank-one secant rule after
    each step (module docstring): returns the best point, the Jacobian taken at ``u`` (the
    uncertainty's: taken before the steps, not at the point returned) and each step's record
    (``objective_before``, ``predicted`` by the linear model, ``objective`` run): what
    :func:`linear_model_warning` reads."""
    from scipy.optimize import lsq_linear
    from tissue_sim_ros.analysis.calibration_search import jacobian
    u = np.asarray(u, dtype=float)
    J = jacobian(fine, u, list(range(len(u))), fd_step=FINISH_FD_STEP)
    B, best = J.copy(), fine.evaluate(u)
    radius, before, record = FINISH_RADIUS, best.objective, []
    for _ in range(steps):
        r = best.residuals
        step = lsq_linear(B, -r, bounds=(np.maximum(-u, -radius), np.minimum(1.0 - u, radius))).x
        candidate = np.clip(u + step, 0.0, 1.0)
        step = candidate - u
        if np.max(np.abs(step)) < MOVE_TOLERANCE:
            break
        predicted = float(np.sum((r + B @ step) ** 2))
        trial = fine.evaluate(candidate)
        record.append({'objective_before': best.objective, 'predicted': predicted, 'objective': trial.objective})
        log(f'fine finish {len(record)}: objective {best.objective:.5g} -> {trial.objective:.5g} (predicted {predicted:.5g})')
        if not trial.failures:   # a failed run's residuals (all misses) say nothing of the slope
            B = broyden_update(B, step, trial.residuals - r)
        if trial.objective < best.objective:
            u, best = candidate, trial
        else:
            radius = 0.5 * np.max(np.abs(step))
    log(f'fine finish: objective {before:.5g} -> {best.objective:.5g} with the fine Jacobian and '
        f'{len(record)} fine run(s)')
    return u, J, record


def linear_model_warning(record, factor: float = LINEAR_MODEL_FACTOR) -> str | None:
    """A warning when a finish step's gain (``objective_before`` - ``objective``) differs from the
    gain its linear model predicted by more than ``factor`` either way: the scene's response is
    then non-linear on the steps' scale, the finish may have stopped short of the optimum, and
    standard errors from that Jacobian are not to be trusted. None when every step agreed."""
    for k, step in enumerate(record, 1):
        predicted = step['objective_before'] - step['predicted']
        actual = step['objective_before'] - step['objective']
        if predicted > 0 and not predicted / factor <= actual <= predicted * factor:
            return (f'fine finish step {k}: its linear model predicted a gain of {predicted:.3g} and the run '
                    f'gained {actual:.3g} (objective {step["objective_before"]:.4g} -> {step["objective"]:.4g}): '
                    'the fit responds non-linearly on the scale of the steps, so the search may have stopped '
                    'short and the standard errors (from that Jacobian) are not reliable; a start nearer the '
                    'values, or fewer keys at once, may go further (more --fine-steps did not on the benchmark)')
    return None
