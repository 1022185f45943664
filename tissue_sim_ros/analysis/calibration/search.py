"""The calibration's search: a staged start, an optional global stage, a joint bounded refinement,
and the uncertainty at the optimum.

The objective is not smooth (a puncture is an event that moves with the parameters), so the
search does what the field does:

1. **global** (optional, ``global_search``): ``'de'`` (or True) is scipy's differential_evolution
   over the unit box, its population evaluated in parallel (``updating='deferred'``), a few
   generations; ``'optuna'`` is Optuna's multivariate TPE sampler (when installed) with the same
   budget, each generation's trials asked for together and evaluated as one parallel batch, the
   start enqueued as the first trial;
2. **staged start**: for each phase of the curve that has fitted keys and samples (loading,
   puncture, inserted, retraction, hold; :data:`~tissue_sim_ros.analysis.calibration.parameters.PHASE_RULES`),
   that phase's keys on that phase's residuals (the puncture keys on the first puncture's force
   and travel errors), the others held: first a scan of each key over ``SCAN_POINTS`` values across its
   bounds (one parallel batch; a threshold the simulation never reaches has no gradient at all,
   so a local method cannot find it from there), the best kept, then a bounded least-squares fit;
3. **joint refinement** (``joint``; the calibration leaves it to the fine finish when it
   searches on a coarse scene): scipy.optimize.least_squares ('trf', bounds [0, 1] in unit
   coordinates) over every key on every residual.

A stage's evaluations run the simulations only as far as its phases need (the objective's
horizons: a loading stage stops them at the first puncture).

Jacobians are forward differences of ``FD_STEP`` in unit coordinates (about 5 % of a decade on a
log key: wider than a step of the simulation's events, narrow enough for the curvature),
stepping inward at a bound; the vectors of one Jacobian run as one parallel batch.

``max_evaluations`` bounds the evaluations of one search; when they are spent the best vector
so far is the result.

Uncertainty: with J the Jacobian of the residuals at the optimum (unit coordinates), m residuals
and n keys, the covariance is s^2 (J^T J)^-1 with s^2 = sum(r^2) / (m - n) (the Gauss-Newton
estimate, as scipy's curve_fit), converted to each key's unit by its d value / d u. Neighbouring
force samples are correlated, so these errors are a lower bound; the correlation matrix says which
keys the data cannot tell apart (pairs above ``CORRELATION_WARNING``).
"""
from __future__ import annotations

import numpy as np

__all__ = ['FD_STEP', 'CORRELATION_WARNING', 'GLOBAL_METHODS', 'STAGE_PHASES', 'search', 'jacobian', 'uncertainty']

FD_STEP = 0.03
SCAN_POINTS = 5
CORRELATION_WARNING = 0.95
#: stage -> the sample phases its residuals come from
STAGE_PHASES = {'loading': ('loading',), 'puncture': 'events', 'inserted': ('inserted',),
                'retraction': ('retraction',), 'hold': ('hold',)}


def jacobian(objective, u, free, phases=None, fd_step=FD_STEP) -> np.ndarray:
    """d residuals / d u over the ``free`` coordinates at ``u`` (forward differences of ``fd_step``
    unit coordinates, backward at the upper bound; one batch)."""
    u = np.asarray(u, dtype=float)
    points, steps = [], []
    for i in free:
        step = fd_step if u[i] + fd_step <= 1.0 else -fd_step
        moved = u.copy()
        moved[i] += step
        points.append(moved)
        steps.append(step)
    residuals = [objective.stage_residuals(e, phases) for e in objective.evaluate_many([u] + points, phases)]
    columns = [(r - residuals[0]) / s for r, s in zip(residuals[1:], steps)]
    return np.stack(columns, axis=1) if columns else np.zeros((residuals[0].size, 0))


def _least_squares(objective, u, free, phases, max_evaluations, fixed_jacobian=None):
    """Bounded least squares over the ``free`` coordinates on a stage's residuals; with
    ``fixed_jacobian`` (residuals x free) that matrix serves every step (a chord method: one
    evaluation a step instead of a Jacobian's batch)."""
    from scipy.optimize import least_squares
    u = np.asarray(u, dtype=float).copy()

    def full(x):
        v = u.copy()
        v[free] = x
        return v

    def fun(x):
        return objective.stage_residuals(objective.evaluate(full(x), phases), phases)

    def jac(x):
        return jacobian(objective, full(x), free, phases) if fixed_jacobian is None else fixed_jacobian
    result = least_squares(fun, u[free], jac=jac, bounds=(0.0, 1.0), method='trf', x_scale=1.0,
                           ftol=1e-3, xtol=1e-3, gtol=1e-6, max_nfev=max_evaluations)
    return full(result.x)


def _scan(objective, u, i, phases) -> np.ndarray:
    """``u`` with coordinate ``i`` at the best of SCAN_POINTS values on a stage's residuals."""
    points = []
    for value in np.linspace(0.0, 1.0, SCAN_POINTS):
        moved = u.copy()
        moved[i] = value
        points.append(moved)
    points.append(u)
    scores = [float(np.sum(objective.stage_residuals(e, phases) ** 2)) for e in objective.evaluate_many(points, phases)]
    return points[int(np.argmin(scores))]


def _popsize(n: int) -> int:
    """Differential evolution's population per key (its population is this x ``n``): about 8
    vectors in all, at least 2 per key."""
    return max(2, -(-8 // n))


def _global(objective, u0, generations, seed):
    from scipy.optimize import differential_evolution

    def batch(function, population):
        return [e.objective for e in objective.evaluate_many(list(population))]
    n = len(u0)
    result = differential_evolution(lambda x: objective.evaluate(x).objective, [(0.0, 1.0)] * n,
                                    x0=np.asarray(u0), maxiter=generations, popsize=_popsize(n),
                                    updating='deferred', workers=batch, polish=False, seed=seed, tol=1e-3)
    return np.asarray(result.x)


def _global_optuna(objective, u0, generations, seed):
    try:
        import optuna
    except ImportError:
        raise ValueError("--global optuna: optuna is not installed (pip install optuna), or use --global de") from None
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    n = len(u0)
    names = [f'u{i}' for i in range(n)]
    space = {name: optuna.distributions.FloatDistribution(0.0, 1.0) for name in names}
    study = optuna.create_study(sampler=optuna.samplers.TPESampler(seed=seed, multivariate=True))
    study.enqueue_trial(dict(zip(names, map(float, u0))))
    for _ in range(generations):      # each generation as large as differential evolution's
        trials = [study.ask(space) for _ in range(_popsize(n) * n)]
        points = [np.array([t.params[name] for name in names]) for t in trials]
        for trial, evaluation in zip(trials, objective.evaluate_many(points)):
            study.tell(trial, evaluation.objective)
    return np.array([study.best_trial.params[name] for name in names])


GLOBAL_METHODS = {'de': _global, 'optuna': _global_optuna}


def search(objective, u0, *, staged=True, global_search=False, generations=5, seed=0,
           stage_evaluations=6, joint_evaluations=20, max_evaluations=None, joint=True, fixed_jacobian=None,
           log=print) -> np.ndarray:
    """The optimum in unit coordinates, from ``u0`` (see the module docstring); ``fixed_jacobian``
    (residuals x keys): the joint refinement's one Jacobian for every step (chord steps)."""
    from tissue_sim_ros.analysis.calibration.objective import BudgetSpent
    u = np.clip(np.asarray(u0, dtype=float), 0.0, 1.0)
    objective.evaluate(u)
    objective.budget = None if max_evaluations is None else len(objective.evaluations) + int(max_evaluations)
    try:
        u = _stages(objective, u, staged, global_search, generations, seed, stage_evaluations,
                    joint_evaluations if joint else 0, fixed_jacobian, log)
    except BudgetSpent:
        log(f'{max_evaluations} evaluations spent: the best so far is the result')
        u = np.asarray(objective.best.u, dtype=float)
    finally:
        objective.budget = None
    best = objective.best
    return np.asarray(best.u if best.objective < objective.evaluate(u).objective else u, dtype=float)


def _stages(objective, u, staged, global_search, generations, seed, stage_evaluations, joint_evaluations,
            fixed_jacobian, log):
    if global_search:
        method = 'de' if global_search is True else global_search
        name = 'differential evolution' if method == 'de' else 'Optuna TPE'
        log(f'global stage: {name}, {generations} generation(s)')
        u = GLOBAL_METHODS[method](objective, u, generations, seed)
    if staged:
        for stage, phases in STAGE_PHASES.items():
            free = [i for i, k in enumerate(objective.keys) if k.phase == stage]
            count = objective.stage_residuals(objective.evaluate(u, phases), phases).size
            if not free or count == 0 or len(free) == len(objective.keys):
                continue
            log(f'staged start: {stage} ({", ".join(objective.keys[i].key for i in free)}) on '
                f'{count} residual(s)')
            for i in free:
                u = _scan(objective, u, i, phases)
            u = _least_squares(objective, u, free, phases, stage_evaluations)
    if not joint_evaluations:
        return u
    log(f'joint refinement: {len(u)} key(s)')
    return _least_squares(objective, u, list(range(len(u))), None, joint_evaluations, fixed_jacobian)


def uncertainty(objective, u, J=None) -> dict:
    """Standard errors (in each key's unit), the correlation matrix and the pairs above
    ``CORRELATION_WARNING``, at ``u`` (see the module docstring); ``J``: a Jacobian already taken
    (None: taken here)."""
    if J is None:
        J = jacobian(objective, u, list(range(len(u))))
    r = objective.evaluate(u).residuals
    m, n = J.shape
    dof = max(m - n, 1)
    covariance = np.linalg.pinv(J.T @ J) * float(r @ r) / dof
    sd = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    with np.errstate(invalid='ignore', divide='ignore'):
        correlation = covariance / np.outer(sd, sd)
    correlation = np.where(np.isfinite(correlation), correlation, 0.0)
    np.fill_diagonal(correlation, 1.0)
    scale = np.array([k.value_per_unit(x) for k, x in zip(objective.keys, u)])
    pairs = [(objective.keys[i].key, objective.keys[j].key, float(correlation[i, j]))
             for i in range(n) for j in range(i + 1, n) if abs(correlation[i, j]) > CORRELATION_WARNING]
    insensitive = [objective.keys[i].key for i in range(n) if not np.any(J[:, i])]
    return {'stderr': sd * np.abs(scale), 'correlation': correlation, 'correlated_pairs': pairs,
            'insensitive': insensitive}
