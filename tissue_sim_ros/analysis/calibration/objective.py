"""The calibration's objective: the comparison's residuals of every fitted trial, as one vector.

A parameter vector (unit coordinates, :mod:`~tissue_sim_ros.analysis.calibration.parameters`)
becomes one simulation per speed of the study (the comparison's plan: the median repeat's
measured motion, :func:`~tissue_sim_ros.analysis.compare.compare.plan_simulations`), and each trial is
compared with its speed's simulation by :func:`~tissue_sim_ros.analysis.compare.compare.compare_trial`,
the same comparison ``tissue-sim compare`` reports. The residuals of a trial are the simulated
minus the measured force at fixed samples (chosen once: evenly over the compared part of the
trial, at most ``points_per_trial``), divided by the trial's force range (so each residual is an
NRMSE contribution) and by the square root of the number of residuals, times the weight of the
sample's phase: the sum of squares is the mean squared NRMSE of the trials. Samples at a
puncture of either curve count 0, as compare's NRMSE leaves them out (a one-sample difference in
when the force drops would dominate the sum); the puncture stage fits the events themselves.

A simulated puncture later (or earlier) than the measured one puts the samples between the two
on opposite sides of the drop: each misses by the drop, and how many there are changes in whole
samples as the parameters move, a staircase no finite difference reads: two such samples can
hold most of a trial's objective, and a Jacobian's predictions then miss by an order of
magnitude. So those samples count 0 too, and each measured
puncture adds one residual instead: the measured drop over the force range times the signed root
of the Huber cost of the matched simulated puncture's shift (k-th with k-th) counted in scored
samples, with the inserted phase's weight (:func:`huber_root`). Its square grows as the shift's
square within half a sample (smooth where the finish works) and by one sample's cost per sample
beyond, as the samples it replaces would. Growing as the square all the way, a shift of ten
samples would weigh ten times what the pointwise error does, and the search would trade the
curve for the puncture's depth.

A run that diverges, trips the watchdog, or whose keys the scene refuses, scores 1 at every
residual (a miss by the whole force range: worse than any run that finishes) and its reason is
logged; a sample the simulation did not reach scores 1 likewise. The samples are chosen among
those the first finished run reached, and the plan's simulations run past the end of every repeat
they are compared with (:mod:`~tissue_sim_ros.analysis.compare.measured_motion`), so a miss is a
run's, not the data's: a sample no run reaches would be a constant in every evaluation, which
stops the search's relative tests early. Nothing is NaN and nothing stops the search.

A stage of the search that fits only the first phases of the curve (the loading before the first
puncture, the puncture itself, the steady insertion) needs the simulations only that far: an
evaluation for ``phases`` runs each speed's simulation to a **horizon**, the latest sample of
those phases over the speed's trials (each on its own contact's clock; for the puncture, the
travel to ``EVENT_REACH`` times the first puncture's depth plus the detector's window, so that a
simulated puncture somewhat deeper than the measured one is still found) plus ``HORIZON_MARGIN_S``
and ``HORIZON_MARGIN_FRACTION`` of it (the simulated contact's lag, the cross-correlation's
shift). On the calibration benchmark the loading ends at a quarter of the slowest speed's run.
Such a partial evaluation scores only its phases (its other samples are misses), so it never
becomes the best; one that does not reach a sample of its phases is run again whole.

Every evaluation is appended to ``evaluations.jsonl`` (parameter values, objective, mean NRMSE,
failures); the simulations are kept in a :class:`~tissue_sim_ros.analysis.compare.trial_simulation.ResultStore`,
so a second run over the same inputs replays them instead of simulating again (resume).
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

__all__ = ['Evaluation', 'Objective', 'FAILED_RESIDUAL', 'BudgetSpent', 'calibrated_spec', 'huber_root',
           'puncture_shift_residuals']

#: the residual of a sample the simulation did not give (diverged, refused, not reached)
FAILED_RESIDUAL = 1.0
#: the phases whose stages may stop the simulations early (module docstring); later phases run whole
PARTIAL_PHASES = ('loading', 'inserted')
#: the puncture stage's simulations run to this multiple of the first puncture's depth
EVENT_REACH = 1.5
#: a horizon's margin: this much time, and this fraction of the time since contact
HORIZON_MARGIN_S = 0.5
HORIZON_MARGIN_FRACTION = 0.05


class BudgetSpent(Exception):
    """The evaluations the search may run are spent (``Objective.budget``)."""


@dataclass
class Evaluation:
    """One parameter vector's outcome."""

    u: tuple
    values: dict
    residuals: np.ndarray
    comparisons: list
    results: list
    failures: list = field(default_factory=list)
    #: the phases a partial evaluation ran for (module docstring); None: the whole curves
    phases: tuple | str | None = None

    @property
    def objective(self) -> float:
        return float(self.residuals @ self.residuals)

    @property
    def nrmse_mean(self) -> float:
        scores = [c.errors.get('nrmse', np.nan) for c in self.comparisons]
        return float(np.nanmean(scores)) if np.isfinite(scores).any() else float('nan')


def puncture_shift_residuals(comparison, indices, error, scale):
    """``error`` (a trial's residuals at the scored samples ``indices``) with the samples strictly
    between each measured puncture and the simulated one matched with it (k-th with k-th) set to
    0, and per measured puncture its shift as one residual: the measured drop over the force
    range ``scale`` times the Huber root of the simulated puncture's shift counted in scored
    samples (0 for a puncture the simulation has no match for). See the module docstring."""
    travel = comparison.travel_since_contact_m
    spacing = np.diff(travel[indices])
    spacing = float(np.median(spacing[spacing > 0])) if np.any(spacing > 0) else 0.0
    shifts = np.zeros(len(comparison.measured_punctures))
    if spacing <= 0:
        return error, shifts
    error = np.array(error, dtype=float)
    for k, (data, sim) in enumerate(zip(comparison.measured_punctures, comparison.simulated_punctures)):
        first, last = sorted((data.index, sim.index))
        error[(indices > first) & (indices <= last)] = 0.0   # both peaks are the last samples before a drop
        shifts[k] = (data.drop_n / scale) * huber_root((sim.travel_m - data.travel_m) / spacing)
    return error, shifts


def huber_root(samples):
    """The signed root of the Huber cost of a shift counted in samples: its square is samples^2
    up to half a sample and |samples| - 1/4 beyond (continuous with its slope), the cost of the
    samples a shift puts on the wrong side of a drop, which grows by one sample's cost per sample."""
    samples = np.asarray(samples, dtype=float)
    cost = np.where(np.abs(samples) <= 0.5, samples * samples, np.abs(samples) - 0.25)
    return np.sign(samples) * np.sqrt(cost)


class Objective:
    """Residuals of the fitted trials for parameter vectors (see the module docstring)."""

    def __init__(self, trials, scene, keys, *, sets_spec=None, align='contact', gap_m=None, tick_s=0.01,
                 points_per_trial=200, phase_weights=None, keep_time_step_s=None, max_mass_scaling=None,
                 store=None, log_path=None, workers=None, scheduler=None, pool=None):
        from tissue_sim_ros.analysis.compare.compare import plan_simulations
        self.trials, self.keys, self.align = list(trials), list(keys), align
        self.base_spec = sets_spec if sets_spec is not None else scene.spec
        self.base_dir = str(scene.base_dir)
        self.scene_gap_m = scene.start_gap_m
        self.plan = plan_simulations(self.trials, scene, gap_m=gap_m, tick_s=tick_s)
        self.points_per_trial = int(points_per_trial)
        self.phase_weights = dict(phase_weights or {})
        self.keep_time_step_s, self.max_mass_scaling = keep_time_step_s, max_mass_scaling
        self.store, self.workers, self.scheduler, self.pool = store, workers, scheduler, pool
        self.log_path = None if log_path is None else Path(log_path)
        self._logged = _logged_keys(self.log_path)       # a resumed run logs each evaluation once
        self._cache: dict = {}           # (vector key, horizon key) -> Evaluation; horizon None: whole
        self._points = None              # per trial: (sample indices, phases there)
        self._horizons: dict = {}        # stage phases -> per job the schedule's end index (None: whole)
        self.simulations_run = 0
        self.best: Evaluation | None = None
        self.on_evaluation = None        # called with each new Evaluation (progress)
        self.budget: int | None = None   # evaluations at most (None: no limit), else BudgetSpent

    @property
    def evaluations(self) -> list[Evaluation]:
        """Every evaluation so far, in the order they were made."""
        return list(self._cache.values())

    # -- parameter vectors to jobs ----------------------------------------------------------------
    def values(self, u) -> dict:
        return {k.key: k.value(x) for k, x in zip(self.keys, u)}

    def spec_for(self, u) -> dict:
        """The scene keys at ``u``: each fitted value set by its key path, checked there."""
        from tissue_sim_ros.engine.scene.keys import set_keys
        return set_keys(self.base_spec, self.values(u))

    def jobs_for(self, u, ends=None) -> list:
        """The simulation jobs of ``u``; ``ends``: per job the schedule's end index (None: whole)."""
        spec = self.spec_for(u)
        ends = ends or [None] * len(self.plan.jobs)
        return [replace(job, scene_spec=spec, keep_time_step_s=self.keep_time_step_s,
                        max_mass_scaling=self.max_mass_scaling, times_s=job.times_s[:end],
                        positions=job.positions[:end])
                for job, end in zip(self.plan.jobs, ends)]

    # -- horizons -----------------------------------------------------------------------------------
    def horizon(self, phases):
        """Per job, the schedule's end index an evaluation for ``phases`` needs (module docstring),
        or None when it needs the whole curves; known after the first (whole) evaluation."""
        if phases is None or self._points is None:
            return None
        key = phases if isinstance(phases, str) else tuple(sorted(phases))
        if key not in self._horizons:
            self._horizons[key] = self._find_horizon(phases)
        return self._horizons[key]

    def _find_horizon(self, phases):
        from tissue_sim_ros.analysis.compare.force_events import PUNCTURE_WINDOW_M
        if phases != 'events' and not set(phases) <= set(PARTIAL_PHASES):
            return None
        first = next(iter(self._cache.values()))       # the first evaluation (whole: it chose the points)
        needed = [0.0] * len(self.plan.jobs)           # per job: time since contact
        for i, (comparison, (indices, sample_phases)) in enumerate(zip(first.comparisons, self._points)):
            since = comparison.time_since_contact_s
            if phases == 'events':
                if not comparison.measured_punctures:
                    continue
                reach = EVENT_REACH * comparison.measured_punctures[0].travel_m + PUNCTURE_WINDOW_M
                beyond = np.flatnonzero(comparison.travel_since_contact_m >= reach)
                if not beyond.size:
                    return None
                t = float(since[beyond[0]])
            else:
                inside = indices[np.isin(sample_phases, phases)]
                if not inside.size:
                    continue
                t = float(since[inside].max())
            job = self.plan.job_of_trial[i]
            needed[job] = max(needed[job], t)
        ends = []
        for job, schedule in enumerate(self.plan.schedules):
            motion = self.plan.motions[self.plan.representative[job]]
            until = float(motion.time_s[motion.contact_index]) + needed[job] * (1.0 + HORIZON_MARGIN_FRACTION) \
                + HORIZON_MARGIN_S
            end = int(np.searchsorted(schedule.trial_time_s, until)) + 1
            ends.append(end if end < len(schedule.times_s) else None)
        return ends if any(end is not None for end in ends) else None

    # -- evaluation ---------------------------------------------------------------------------------
    @staticmethod
    def _key(u) -> tuple:
        return tuple(round(float(x), 12) for x in u)

    def evaluate_many(self, us, phases=None) -> list[Evaluation]:
        """The evaluations of the vectors ``us``: their simulations in one parallel batch (those
        already run or stored are reused). ``phases``: only those phases' residuals are wanted
        (a stage's, :meth:`stage_residuals`): the simulations may stop at their horizon."""
        ends = self.horizon(phases)
        scope = None if ends is None else phases
        keys = [self._key(u) for u in us]
        found = {k: self._cache.get((k, None)) or self._cache.get((k, str(scope))) for k in keys}
        new = list(dict.fromkeys(k for k in keys if found[k] is None))
        if new and self.budget is not None and len(self._cache) + len(new) > self.budget:
            raise BudgetSpent(f'{self.budget} evaluations spent')
        for k, evaluation in zip(new, self._run(new, ends, scope)):
            if scope is not None and self._short_of(evaluation, phases):
                evaluation = self._run([k], None, None)[0]        # the horizon fell short: whole
            found[k] = self._cache[(k, None if evaluation.phases is None else str(scope))] = evaluation
            self._log(evaluation)
            if evaluation.phases is None and (self.best is None or evaluation.objective < self.best.objective):
                self.best = evaluation
            if self.on_evaluation is not None:
                self.on_evaluation(evaluation)
        return [found[k] for k in keys]

    def _run(self, vectors, ends, phases) -> list[Evaluation]:
        """The vectors' simulations to ``ends`` (one batch), scored."""
        from tissue_sim_ros.analysis.compare.trial_simulation import SimulationResult, simulate
        from tissue_sim_ros.analysis.jobs import run_jobs
        from tissue_sim_ros.errors import InputError
        jobs, results = [], []
        for k in vectors:
            try:
                vector_jobs = self.jobs_for(k, ends)
            except InputError as exc:          # a value the scene refuses: scored as a miss
                cut = ends or [None] * len(self.plan.jobs)
                results += [SimulationResult.refused(len(job.times_s[:end]), exc)
                            for job, end in zip(self.plan.jobs, cut)]
                jobs += [None] * len(self.plan.jobs)
                continue
            jobs += vector_jobs
            results += [self.store.get(job.key) if self.store is not None else None for job in vector_jobs]
        todo = [i for i, r in enumerate(results) if r is None]

        def keep(position, result):
            results[todo[position]] = result
            if self.store is not None:
                self.store.put(jobs[todo[position]].key, result)
        run_jobs(simulate, [jobs[i] for i in todo], workers=self.workers, scheduler=self.scheduler,
                 on_result=keep, quiet=True, pool=self.pool)
        self.simulations_run += len(todo)
        per = len(self.plan.jobs)
        return [self._score(k, results[n * per:(n + 1) * per], ends, phases) for n, k in enumerate(vectors)]

    def _short_of(self, evaluation: Evaluation, phases) -> bool:
        """Whether a partial evaluation left a sample of ``phases`` unreached (not diverged)."""
        if evaluation.failures or phases == 'events':     # a puncture beyond the reach is a miss
            return False
        return any(np.any(np.isnan(c.simulated_n[indices[np.isin(p, phases)]]))
                   for c, (indices, p) in zip(evaluation.comparisons, self._points))

    def evaluate(self, u, phases=None) -> Evaluation:
        return self.evaluate_many([u], phases)[0]

    def _score(self, u, results, ends=None, phases=None) -> Evaluation:
        from tissue_sim_ros.analysis.compare.compare import compare_trial, simulated_curve
        plan = self.plan
        ends = ends or [None] * len(plan.jobs)
        curves = [simulated_curve(results[j], _cut(plan.schedules[j], ends[j]), plan.motions[plan.representative[j]],
                                  self.scene_gap_m) for j in range(len(plan.jobs))]
        comparisons = [compare_trial(trial, plan.motions[i], curves[plan.job_of_trial[i]], self.align)
                       for i, trial in enumerate(self.trials)]
        if self._points is None:
            self._points = [self._choose_points(c) for c in comparisons]
        failures = sorted({r.diverged for r in results if r.diverged})
        residuals = np.concatenate([self._trial_residuals(c, *points)
                                    for c, points in zip(comparisons, self._points)])
        return Evaluation(u, self.values(u), residuals, comparisons, list(results), failures,
                          None if all(end is None for end in ends) else phases)

    def _choose_points(self, comparison):
        """The samples a trial is scored at: after its contact (the insertion only with the
        depth alignment), evenly spaced; with a first run that finished, those it reached (a
        repeat that went deeper than the one its speed's simulation follows, with the depth
        alignment: its deepest samples have no simulated force by design, not by a failure)."""
        phases = comparison.phases
        eligible = phases != 'approach'
        if self.align == 'depth':
            eligible &= np.isin(phases, ('loading', 'inserted'))
        if not comparison.diverged and np.isfinite(comparison.simulated_n).any():
            eligible &= np.isfinite(comparison.simulated_n)
        candidates = np.flatnonzero(eligible)
        if candidates.size > self.points_per_trial:
            candidates = candidates[np.linspace(0, candidates.size - 1, self.points_per_trial).round().astype(int)]
        return candidates, phases[candidates]

    def _trial_residuals(self, comparison, indices, phases) -> np.ndarray:
        from tissue_sim_ros.analysis.compare.compare import away_from_events
        measured = comparison.measured_n
        scale = float(np.ptp(measured)) or 1.0
        simulated = comparison.simulated_n[indices]
        error = np.where(np.isfinite(simulated), (simulated - measured[indices]) / scale, FAILED_RESIDUAL)
        shifts = np.full(len(comparison.measured_punctures), FAILED_RESIDUAL)
        if not comparison.diverged:      # compare's NRMSE leaves the samples at a puncture out; so does this
            away = away_from_events(comparison.travel_since_contact_m,
                                     comparison.measured_punctures + comparison.simulated_punctures)
            error = np.where(away[indices], error, 0.0)
            error, shifts = puncture_shift_residuals(comparison, indices, error, scale)
        weights = np.array([self.phase_weights.get(p, 1.0) for p in phases])
        total = sum(len(points[0]) for points in self._points)
        shift_weight = self.phase_weights.get('inserted', 1.0)
        return np.concatenate([error * weights, shifts * shift_weight]) / np.sqrt(max(total, 1))

    def stage_residuals(self, evaluation: Evaluation, phases=None) -> np.ndarray:
        """The residuals a stage of the search fits: those of samples in ``phases`` (None: all),
        or for ``phases == 'events'`` the first puncture of each trial that has one: its force
        error over the trial's force range and its travel error over the trial's travel range
        (a simulation without a puncture there scores 1 on both)."""
        if phases is None:
            return evaluation.residuals
        if phases == 'events':
            out = []
            for c in evaluation.comparisons:
                if not c.measured_punctures:
                    continue
                force = c.events.get('first_puncture_force_error_n', np.nan) / (float(np.ptp(c.measured_n)) or 1.0)
                travel = c.events.get('first_puncture_travel_error_m', np.nan) / (
                    float(np.ptp(c.travel_since_contact_m)) or 1.0)
                out += [force if np.isfinite(force) else FAILED_RESIDUAL,
                        travel if np.isfinite(travel) else FAILED_RESIDUAL]
            return np.array(out)
        mask = np.concatenate([np.concatenate([np.isin(p, tuple(phases)), np.zeros(len(c.measured_punctures), bool)])
                               for (_, p), c in zip(self._points, evaluation.comparisons)])
        return evaluation.residuals[mask]

    def _log(self, evaluation: Evaluation) -> None:
        if self.log_path is None:
            return
        phases = None if evaluation.phases is None else str(evaluation.phases)
        key = _log_key(evaluation.values, phases)
        if key in self._logged:
            return
        self._logged.add(key)
        record = {'time': time.strftime('%Y-%m-%dT%H:%M:%S'), 'values': evaluation.values, 'phases': phases,
                  'objective': evaluation.objective, 'nrmse_mean': evaluation.nrmse_mean,
                  'failures': evaluation.failures,
                  'mass_scaling': max((r.mass_scaling for r in evaluation.results), default=float('nan'))}
        with self.log_path.open('a') as log:
            log.write(json.dumps(record, default=float) + '\n')


def _log_key(values: dict, phases) -> str:
    return json.dumps([values, phases], sort_keys=True, default=float)


def _logged_keys(path) -> set:
    """The evaluations an earlier run of the study logged (a line cut by a kill is skipped)."""
    keys = set()
    if path is None or not path.exists():
        return keys
    text = path.read_text()
    if text and not text.endswith('\n'):
        with path.open('a') as log:                      # the next record starts on its own line
            log.write('\n')
    for line in text.splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue
        keys.add(_log_key(record.get('values'), record.get('phases')))
    return keys


def _cut(schedule, end):
    """``schedule`` up to its sample ``end`` (None: whole)."""
    if end is None:
        return schedule
    return replace(schedule, times_s=schedule.times_s[:end], positions=schedule.positions[:end],
                   travel_m=schedule.travel_m[:end], trial_time_s=schedule.trial_time_s[:end])


def calibrated_spec(fit: dict) -> dict:
    """The scene keys of a calibration's optimum, with the mass scaling it ran with (and the
    damping rate that keeps the scene's damping force at it)."""
    from tissue_sim_ros.engine.scene.keys import with_mass_scaling
    return with_mass_scaling(fit['objective'].spec_for(fit['u']), fit['inertia']['mass_scaling_at_optimum'])
