"""The calibration's search: a staged start, an optional global stage, a joint bounded refinement,
and the uncertainty at the optimum.

The objective is not smooth (a puncture is an event that moves with the parameters), so the
search does what the field does:

1. **global** (optional, ``global_search``): ``'de'`` (or True) is scipy's differential_evolution
   over the unit box, its population evaluated in parallel (``updating='deferred'``), a few
   generations; ``'optuna'`` is Optuna's multivariate TPE sampler (when installed) with the same
   budget, each generation's trials asked for together and evaluated as one parallel batch, the
   start enqueued as the first trial;
2. **staged start**, layer by layer (:mod:`~tissue_sim_ros.analysis.calibration.stages`: each
   layer's loading, its puncture, the level after it; then the retraction and the pause): each
   stage's keys on the residuals of the samples where they act (a puncture's keys also on that
   layer's puncture force and depth errors), the others held: first a scan of each puncture key
   over ``SCAN_POINTS`` values across its bounds (one parallel batch; a threshold the simulation
   never reaches has no gradient at all, so a local method cannot find it from there), the best
   kept, then a bounded least-squares fit. Each stage ends with a whole evaluation, recorded with its
   own residuals' objective before and after (``record``); the staged start hands on the best
   whole evaluation it made, so it never leaves the fit worse than its start. A start already
   optimal ends the search at once: its fit within the data's noise floor (``enough``) and the
   Gauss-Newton step from its Jacobian (which then gives the standard errors) gaining less than
   ``OPTIMAL_GAIN`` of its objective;
3. **joint refinement** (``joint``; the calibration leaves it to the fine finish when it
   searches on a coarse scene): scipy.optimize.least_squares ('trf', bounds [0, 1] in unit
   coordinates) over every key on every residual.

A stage's evaluations run the simulations only as far as its phases need (the objective's
horizons: a loading stage stops them at the first puncture).

Jacobians are forward differences of ``FD_STEP`` in unit coordinates (about 5 % of a decade on a
log key: wider than a step of the simulation's events, narrow enough for the curvature),
stepping inward at a bound; the vectors of one Jacobian run as one parallel batch.

The objective's :class:`~tissue_sim_ros.analysis.calibration.objective.Budget` bounds the
evaluations (``max_evaluations`` makes one when the objective has none); when they are spent the
best vector so far is the result.

What the data cannot tell apart (:func:`weakest_direction`): the correlations name pairs; three
keys or more can trade along one combination without any pair standing out (on a three-layer
phantom the middle and core moduli at -0.92, the outer one with them). The right singular vector
of J with the least singular value is the combination the data determines least; the fit at the
optimum stepped ``WEAK_REACH`` along it either way (in the key that moves most) is measured, not
extrapolated. The repeats are independent measurements of one curve, so an end is told apart
from the optimum when the repeats agree it fits worse: the mean over the trials of its part of
the objective less the optimum's at least ``TOLD_APART_T`` standard errors of that mean (a paired
comparison, on what the search minimises: the NRMSE leaves the samples at a puncture out and the
objective holds the punctures' force and depth errors, so the NRMSE can favour an end the
objective does not; the repeats' noise floor is no measure of it either: most of it is the
punctures' spread). Unless both ends are told apart, the data cannot tell those values apart.

Uncertainty: with J the Jacobian of the residuals at the optimum (unit coordinates), m residuals
and n keys, the covariance is s^2 (J^T J)^-1 with s^2 = sum(r^2) / (m - n) (the Gauss-Newton
estimate, as scipy's curve_fit), converted to each key's unit by its d value / d u. Neighbouring
force samples are correlated, so these errors are a lower bound; the correlation matrix says which
keys the data cannot tell apart (pairs above ``CORRELATION_WARNING``).
"""
from __future__ import annotations

import numpy as np

__all__ = ['FD_STEP', 'CORRELATION_WARNING', 'GLOBAL_METHODS', 'search', 'jacobian', 'uncertainty', 'why_not_moved',
           'weakest_direction']

FD_STEP = 0.03
SCAN_POINTS = 5
CORRELATION_WARNING = 0.95
#: a start within the noise floor whose Gauss-Newton step would gain less than this fraction of its
#: objective is already optimal: the search ends there
OPTIMAL_GAIN = 0.02
#: a key that moved less than this (unit coordinates) did not move; one this near a bound is at it
MOVED, AT_BOUND = 0.01, 1e-3
#: a key whose Jacobian column is below this fraction of the largest does not change the curves
INSENSITIVE = 1e-3
#: the probe of the least-determined combination steps this far (unit coordinates) in the key that
#: moves most (10-25 % of a value on the proposal's bounds); keys moving under a tenth of it are left out
WEAK_REACH = 0.1
#: the evaluations the probe takes (both ends, one batch)
WEAK_EVALUATIONS = 2
#: an end of the probe fits worse than the optimum when the mean over the trials of its part of the
#: objective's increase is at least this many standard errors of that mean (about a one-sided 95 %
#: test with five repeats)
TOLD_APART_T = 2.0


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
           log=print, record=None, enough=None) -> np.ndarray:
    """The optimum in unit coordinates, from ``u0`` (see the module docstring); ``fixed_jacobian``
    (residuals x keys): the joint refinement's one Jacobian for every step (chord steps);
    ``record``: a list each stage appends its record to; ``enough(evaluation)``: True when a fit is
    as close to the data as the data's repeats are to each other."""
    from tissue_sim_ros.analysis.calibration.objective import Budget, BudgetSpent
    u = np.clip(np.asarray(u0, dtype=float), 0.0, 1.0)
    own_budget = max_evaluations is not None and getattr(objective, 'budget', None) is None
    if own_budget:
        objective.budget = Budget(len(objective.evaluations) + int(max_evaluations))
    record = [] if record is None else record
    try:
        start = objective.evaluate(u)
        if enough is not None and enough(start):
            J = jacobian(objective, u, list(range(len(u))))
            gain = _predicted_gain(J, start.residuals, u)
            if gain <= OPTIMAL_GAIN * start.objective:
                log(f'the start is already optimal: its fit is as close to the data as the repeats are to each '
                    f'other (NRMSE {start.nrmse_mean:.4f}) and a Gauss-Newton step would gain '
                    f'{gain / max(start.objective, 1e-300):.1%} of its objective; the search ends here')
                record.append({'stage': 'start', 'stopped': 'already optimal', 'nrmse': start.nrmse_mean,
                               'predicted_gain': gain / max(start.objective, 1e-300), 'jacobian': J})
                return u
            log(f'the start is within the noise floor (NRMSE {start.nrmse_mean:.4f}), but a step would gain '
                f'{gain / max(start.objective, 1e-300):.1%} of its objective: searching on')
        u = _stages(objective, u, staged, global_search, generations, seed, stage_evaluations,
                    joint_evaluations if joint else 0, fixed_jacobian, log, record)
    except BudgetSpent as spent:
        log(f'evaluations spent ({spent}): the best so far is the result')
        record.append({'stage': 'budget', 'stopped': str(spent)})
        u = np.asarray(objective.best.u, dtype=float)
    finally:
        if own_budget:
            objective.budget = None
    best = objective.best
    return np.asarray(best.u if best.objective < objective.evaluate(u).objective else u, dtype=float)


def _predicted_gain(J, r, u) -> float:
    """What the bounded Gauss-Newton step from ``u`` would take off the objective r.r, by its
    linear model (scipy lsq_linear)."""
    from scipy.optimize import lsq_linear
    if J.size == 0:
        return 0.0
    step = lsq_linear(J, -r, bounds=(-u, 1.0 - u)).x
    return float(r @ r - np.sum((r + J @ step) ** 2))


def _stage_list(objective):
    from tissue_sim_ros.analysis.calibration.stages import plan_stages
    return plan_stages(objective.keys, getattr(objective, 'regions', []), getattr(objective, 'n_layers', 0))


def _stages(objective, u, staged, global_search, generations, seed, stage_evaluations, joint_evaluations,
            fixed_jacobian, log, record):
    if global_search:
        method = 'de' if global_search is True else global_search
        name = 'differential evolution' if method == 'de' else 'Optuna TPE'
        log(f'global stage: {name}, {generations} generation(s)')
        u = GLOBAL_METHODS[method](objective, u, generations, seed)
    if staged:
        start_whole = objective.evaluate(u).objective
        for stage in _stage_list(objective):
            free = list(stage.free)
            before = objective.stage_residuals(objective.evaluate(u, stage), stage)
            if before.size == 0 or len(free) == len(objective.keys):
                continue
            log(f'staged start: {stage.name} ({", ".join(objective.keys[i].key for i in free)}) on '
                f'{before.size} residual(s)')
            entry = {'stage': stage.name, 'keys': [objective.keys[i].key for i in free],
                     'residuals': int(before.size), 'objective_before': float(before @ before),
                     'whole_before': objective.evaluate(u).objective, 'values_before': objective.values(u)}
            record.append(entry)
            for i in free:          # a threshold the simulation does not reach has no gradient: scan it
                if objective.keys[i].phase == 'puncture':
                    u = _scan(objective, u, i, stage)
            u = _least_squares(objective, u, free, stage, stage_evaluations)
            after = objective.stage_residuals(objective.evaluate(u, stage), stage)
            entry.update(objective_after=float(after @ after), whole_after=objective.evaluate(u).objective,
                         values_after=objective.values(u))
            log(f'  {stage.name}: its objective {entry["objective_before"]:.4g} -> {entry["objective_after"]:.4g}; '
                f'every residual {entry["whole_before"]:.4g} -> {entry["whole_after"]:.4g}')
        best = objective.best
        if best is not None and best.objective < objective.evaluate(u).objective:
            log(f'staged start: its best whole evaluation ({best.objective:.4g}, not its last) goes on')
            u = np.asarray(best.u, dtype=float)
        record.append({'stage': 'staged start', 'whole_before': start_whole,
                       'whole_after': objective.evaluate(u).objective})
    if not joint_evaluations:
        return u
    log(f'joint refinement: {len(u)} key(s)')
    before = objective.evaluate(u).objective
    u = _least_squares(objective, u, list(range(len(u))), None, joint_evaluations, fixed_jacobian)
    record.append({'stage': 'joint refinement', 'keys': [k.key for k in objective.keys], 'whole_before': before,
                   'whole_after': objective.evaluate(u).objective})
    return u


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
            'insensitive': insensitive, 'jacobian_matrix': J}


def why_not_moved(objective, u0, u, J, correlation) -> dict:
    """Per fitted key: whether it moved from its start (more than ``MOVED`` in unit coordinates)
    and, when not, why: at a bound (its gradient pushing past it), insensitive (its Jacobian column
    below ``INSENSITIVE`` of the largest: it does not change the fitted curves), correlated with
    another key (above ``CORRELATION_WARNING``: the data cannot tell them apart), or at its optimum
    (its gradient there is zero to the data's precision, so the start was already its best value);
    ``pushed_past``: the bound ('lower', 'upper') it ended at with the fit pushing past it, moved or
    not (the other keys then make up for it), else None."""
    r = objective.evaluate(u).residuals
    gradient = J.T @ r if J.size else np.zeros(len(u))
    norms = np.linalg.norm(J, axis=0) if J.size else np.zeros(len(u))
    largest = float(norms.max()) if norms.size else 0.0
    out = {}
    for i, key in enumerate(objective.keys):
        moved = abs(float(u[i]) - float(u0[i])) > MOVED
        reasons = []
        past = None
        if u[i] <= AT_BOUND and gradient[i] > 0 or u[i] >= 1 - AT_BOUND and gradient[i] < 0:
            past = 'lower' if u[i] <= AT_BOUND else 'upper'
            reasons.append(f'at its {past} bound, the fit pushing past it')
        if largest > 0 and norms[i] < INSENSITIVE * largest or largest == 0:
            reasons.append('insensitive: it does not change the fitted curves')
        partners = [objective.keys[j].key for j in range(len(u))
                    if j != i and abs(correlation[i, j]) > CORRELATION_WARNING]
        if partners:
            reasons.append(f'correlated with {", ".join(partners)}: the data cannot tell them apart')
        if not reasons:
            reasons.append('at its optimum: the start was already its best value')
        out[key.key] = {'moved': bool(moved), 'why': None if moved else '; '.join(reasons),
                        'at_bound': bool(u[i] <= AT_BOUND or u[i] >= 1 - AT_BOUND), 'pushed_past': past}
    return out


def _worse(end, at) -> float:
    """The paired statistic of an end against the optimum: the mean over the trials of its part of
    the objective less the optimum's, over that mean's standard error (inf when every difference
    is equal and positive; NaN with fewer than two trials)."""
    if len(end.trial_sizes) < 2 or len(at.trial_sizes) != len(end.trial_sizes):
        return float('nan')
    difference = end.trial_objectives() - at.trial_objectives()
    error = float(np.std(difference, ddof=1)) / np.sqrt(difference.size)
    mean = float(difference.mean())
    return mean / error if error > 0 else (np.inf if mean > 0 else -np.inf if mean < 0 else 0.0)


def weakest_direction(objective, u, J, noise_floor: float) -> dict | None:
    """The combination of keys the data determines least, probed (module docstring): per key
    taking part, its value at the optimum and at both ends of the probe; the fit NRMSE and the
    objective at the minus end, the optimum and the plus end; per end the paired statistic against
    the optimum (``worse_t``); ``told_apart`` True when both reach ``TOLD_APART_T``, None with
    fewer than two trials; ``noise_floor`` for the reader. None with fewer than two keys, or when
    the budget has no room left."""
    from tissue_sim_ros.analysis.calibration.objective import BudgetSpent
    if J.ndim != 2 or J.shape[1] < 2 or not np.any(J):
        return None
    u = np.asarray(u, dtype=float)
    vector = np.linalg.svd(J, full_matrices=False)[2][-1]
    vector = vector / vector[np.argmax(np.abs(vector))] * WEAK_REACH      # the largest step positive
    ends = [np.clip(u - vector, 0.0, 1.0), np.clip(u + vector, 0.0, 1.0)]
    try:
        probed = objective.evaluate_many(ends)
    except BudgetSpent:
        return None
    at = objective.evaluate(u)
    keys = {key.key: {'value': key.value(u[i]), 'minus': key.value(ends[0][i]), 'plus': key.value(ends[1][i])}
            for i, key in enumerate(objective.keys) if abs(vector[i]) >= 0.1 * WEAK_REACH}
    worse = [_worse(end, at) for end in probed]
    told = None if not all(np.isfinite(t) or np.isinf(t) for t in worse) else \
        bool(all(t >= TOLD_APART_T for t in worse))
    return {'keys': keys, 'nrmse': [probed[0].nrmse_mean, at.nrmse_mean, probed[1].nrmse_mean],
            'objective': [probed[0].objective, at.objective, probed[1].objective],
            'worse_t': [float(t) for t in worse], 'noise_floor': float(noise_floor), 'told_apart': told}
