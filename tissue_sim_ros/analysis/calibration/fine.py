"""Coarse to fine: after the staged start on the cheap scene, re-fit the loading's keys on the
scene as asked, then finish there with its own Jacobian.

A coarser mesh is not the same tissue. Its linear tetrahedra lock more (the liver's Poisson ratio
is 0.45) and its contact patch is coarser, so it is stiffer: its optimum can have every other
key close to the truth and Young's modulus far too low. The stiffness and the law act on the
loading before the first puncture, so they are fitted again on the scene as asked, on the loading
alone (:func:`refit_loading`: ``REFIT_STEPS`` Gauss-Newton steps from the coarse optimum on the
loading's residuals, the simulations stopped at the first puncture by the objective's horizons,
a quarter of a whole run).

Then the **fine finish** (:func:`fine_finish`) over every key on every residual. Both are
:func:`gauss_newton`: the scene's own Jacobian at the start point (one parallel batch; forward
differences of ``FINISH_FD_STEP``), then Gauss-Newton steps, each the bounded linear
least-squares step (scipy lsq_linear), shortened along its own direction to at most
``FINISH_RADIUS`` in any unit coordinate (the radius halved after a step that does not lower the
objective), the Jacobian updated after each by Broyden's rank-one secant rule so that no further
batch is spent. Shortened, not clipped to a box: the loading cannot tell the law's amplitude
from the stiffness well (on the benchmark the loading Jacobian's singular values are 0.28 and
0.0017, the second almost all amplitude), and with the step solved inside a box the stiffness's
long step would stop at the box's face and the amplitude take up the rest. The Jacobian is
updated, not held: chord steps with it held converge only linearly. The first Jacobian gives the
standard errors: the fine scene's, though taken where the finish started, not at the point it
returns (another batch would cost as much again; the report says so).

Not output space mapping (Bandler et al. 2004: the coarse residuals shifted to agree with the
fine ones where last run, searched again): its fixed point is not the fine optimum when the
coarse scene responds to the keys along other directions, as a coarse mesh does (its Jacobian
36-141 % off the fine one per key on the benchmark). Figures: docs/performance.md.
"""
from __future__ import annotations

import numpy as np

__all__ = ['REFIT_STEPS', 'FINISH_FD_STEP', 'broyden_update', 'fine_finish', 'gauss_newton',
           'linear_model_warning', 'refit_loading']

#: the loading's re-fit moves only along directions the loading determines at least this well
#: relative to the best determined one (:func:`_step`; module docstring)
REFIT_RCOND = 0.05
#: a step that moves less than this (unit coordinates, every key) ends the finish
MOVE_TOLERANCE = 1e-3
#: Gauss-Newton steps of the loading's re-fit on the scene as asked (one partial evaluation each)
REFIT_STEPS = 3
#: the fine finish's forward-difference step in unit coordinates (the search's)
FINISH_FD_STEP = 0.03
#: the longest step in any unit coordinate (a longer step is shortened along its direction;
#: halved after a step that does not lower the objective)
FINISH_RADIUS = 0.25
#: a finish step whose gain differs from its linear model's prediction by more than this factor
#: is reported (:func:`linear_model_warning`)
LINEAR_MODEL_FACTOR = 3.0


def broyden_update(B: np.ndarray, step: np.ndarray, change: np.ndarray) -> np.ndarray:
    """B + (change - B step) step^T / |step|^2 (Broyden, Math. Comp. 19, 1965): the Jacobian that
    maps ``step`` onto the residual ``change`` it caused, unchanged across directions orthogonal
    to the step."""
    return B + np.outer(change - B @ step, step) / float(step @ step)


def gauss_newton(objective, u, *, steps: int, free=None, phases=None, rcond=None, enough=None, label='fine finish',
                 log=print):
    """At most ``steps`` Gauss-Newton steps (one evaluation each) over the ``free`` keys (None:
    all) on ``phases``' residuals (None: all; a stage's, whose simulations stop at their horizon),
    from ``objective``'s own Jacobian at ``u``, updated by Broyden's rank-one secant rule after each
    step (module docstring). ``rcond``: each step only along the Jacobian's right singular vectors
    whose singular value is at least this fraction of the largest (:func:`_step`). ``enough``:
    called with each accepted evaluation, True ends the steps (the fit is as close to the data as
    the data's own repeats are to each other). Without residuals in ``phases``, ``u`` as it is.
    Returns the best point, the Jacobian taken at ``u`` and each step's
    record (``objective_before``, ``predicted`` by the linear model, ``objective`` run, on those
    residuals): what :func:`linear_model_warning` reads."""
    from tissue_sim_ros.analysis.calibration.search import jacobian
    u = np.asarray(u, dtype=float)
    free = list(range(len(u))) if free is None else list(free)
    J = jacobian(objective, u, free, phases, fd_step=FINISH_FD_STEP)
    B, r = J.copy(), objective.stage_residuals(objective.evaluate(u, phases), phases)
    radius, before, record = FINISH_RADIUS, float(r @ r), []
    if r.size == 0:
        return u, J, record
    for _ in range(steps):
        if enough is not None and enough(objective.evaluate(u, phases)):
            log(f'{label}: the fit is as close to the data as its repeats are to each other; no more steps')
            break
        x = u[free]
        step = _step(B, r, x, rcond)
        step *= min(1.0, radius / max(float(np.max(np.abs(step))), np.finfo(float).tiny))
        if np.max(np.abs(step)) < MOVE_TOLERANCE:
            break
        candidate = u.copy()
        candidate[free] = np.clip(x + step, 0.0, 1.0)
        current, predicted = float(r @ r), float(np.sum((r + B @ step) ** 2))
        trial = objective.evaluate(candidate, phases)
        moved = objective.stage_residuals(trial, phases)
        record.append({'objective_before': current, 'predicted': predicted, 'objective': float(moved @ moved)})
        log(f'{label} {len(record)}: objective {current:.5g} -> {moved @ moved:.5g} (predicted {predicted:.5g})')
        if not trial.failures:   # a failed run's residuals (all misses) say nothing of the slope
            B = broyden_update(B, step, moved - r)
        if moved @ moved < current:
            u, r = candidate, moved
        else:
            radius = 0.5 * np.max(np.abs(step))
    log(f'{label}: objective {before:.5g} -> {r @ r:.5g} with its own Jacobian and {len(record)} run(s)')
    return u, J, record


def _step(B, r, x, rcond) -> np.ndarray:
    """The Gauss-Newton step from ``x`` (unit coordinates) for residuals ``r`` and Jacobian ``B``:
    the bounded least-squares one (scipy lsq_linear) without ``rcond``; with it, the least-squares
    step within the span of the right singular vectors whose singular value is at least ``rcond``
    of the largest (truncated SVD: a direction the residuals hardly see is not moved along),
    shortened along its direction to stay within the bounds."""
    from scipy.optimize import lsq_linear
    if rcond is None:
        return lsq_linear(B, -r, bounds=(-x, 1.0 - x)).x
    U, S, Vt = np.linalg.svd(B, full_matrices=False)
    keep = S >= rcond * S[0] if S.size and S[0] > 0 else np.zeros(S.size, dtype=bool)
    step = Vt[keep].T @ ((U[:, keep].T @ -r) / S[keep])
    with np.errstate(divide='ignore', invalid='ignore'):      # the room to each bound along the step
        room = np.where(step > 0, (1.0 - x) / step, np.where(step < 0, -x / step, np.inf))
    return step * min(1.0, float(np.min(room, initial=np.inf)))


def refit_loading(fine, u, *, steps: int = REFIT_STEPS, log=print) -> np.ndarray:
    """``u`` with the keys that act on the loading (calibration_parameters.PHASE_RULES) fitted
    again on the loading residuals of ``fine`` by :func:`gauss_newton` (module docstring); ``u``
    as it is when no key acts there or the data has no loading."""
    u = np.asarray(u, dtype=float)
    free = [i for i, k in enumerate(fine.keys) if k.phase == 'loading']
    if not free or not steps:
        return u
    names = ', '.join(fine.keys[i].key for i in free)
    return gauss_newton(fine, u, steps=steps, free=free, phases=('loading',), rcond=REFIT_RCOND, log=log,
                        label=f'loading re-fit on the scene as asked ({names})')[0]


def fine_finish(fine, u, *, steps: int, noise_floor: float = float('nan'), log=print):
    """:func:`gauss_newton` over every key on every residual of the scene as asked (module
    docstring); its first Jacobian is the uncertainty's (taken before the steps). It stops once
    the fitted trials' mean NRMSE is within ``noise_floor``, the data's own repeat-to-repeat
    NRMSE (Morozov's discrepancy principle: closer than its noise the data tells no fit apart)."""
    def enough(evaluation):
        return bool(np.isfinite(noise_floor) and evaluation.nrmse_mean <= noise_floor)
    return gauss_newton(fine, u, steps=steps, enough=enough, log=log)


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
                    'values, more --fine-steps, or fewer keys at once may go further')
    return None
