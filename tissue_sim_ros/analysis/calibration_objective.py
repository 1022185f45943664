"""The calibration's objective: the comparison's residuals of every fitted trial, as one vector.

A parameter vector (unit coordinates, :mod:`~tissue_sim_ros.analysis.calibration_parameters`)
becomes one simulation per speed of the study (the comparison's plan: the median repeat's
measured motion, :func:`~tissue_sim_ros.analysis.compare.plan_simulations`), and each trial is
compared with its speed's simulation by :func:`~tissue_sim_ros.analysis.compare.compare_trial`,
the same comparison ``tissue-sim compare`` reports. The residuals of a trial are the simulated
minus the measured force at fixed samples (chosen once: evenly over the compared part of the
trial, at most ``points_per_trial``), divided by the trial's force range (so each residual is an
NRMSE contribution) and by the square root of the number of residuals, times the weight of the
sample's phase: the sum of squares is the mean squared NRMSE of the trials. Samples at a
puncture of either curve count 0, as compare's NRMSE leaves them out (a one-sample difference in
when the force drops would dominate the sum); the puncture stage fits the events themselves.

A simulated puncture later (or earlier) than the measured one puts the samples between the two
on opposite sides of the drop: each misses by the drop, and how many there are changes in whole
samples as the parameters move, a staircase no finite difference reads. On the calibration
benchmark two such samples held 82 % of a trial's objective at the search's result, and the fine
Jacobian's predictions missed by 12-21x. So those samples count 0 too, and each measured
puncture adds one residual instead: the measured drop over the force range times the shift of
the matched simulated puncture (k-th with k-th) counted in scored samples, a smooth measure
equal to the samples' cost at a shift of one sample and growing as its square beyond (with the
inserted phase's weight). On the benchmark's stored runs the fine finish then reached the
objective of the true values (5.3e-5 against 5.1e-5, from 0.0083) where it had stopped at 8x it.

A run that diverges, trips the watchdog, or whose keys the scene refuses, scores 1 at every
residual (a miss by the whole force range: worse than any run that finishes) and its reason is
logged; a sample the simulation did not reach scores 1 likewise. The samples are chosen among
those the first finished run reached, and the plan's simulations run past the end of every repeat
they are compared with (:mod:`~tissue_sim_ros.analysis.measured_motion`), so a miss is a run's,
not the data's: the last sample of a jittered recording scoring 1 in every run was a constant
that made the search's relative tests stop early. Nothing is NaN and nothing stops the search.

Every evaluation is appended to ``evaluations.jsonl`` (parameter values, objective, mean NRMSE,
failures); the simulations are kept in a :class:`~tissue_sim_ros.analysis.trial_simulation.ResultStore`,
so a second run over the same inputs replays them instead of simulating again (resume).
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

__all__ = ['Evaluation', 'Objective', 'FAILED_RESIDUAL', 'BudgetSpent', 'puncture_shift_residuals']

#: the residual of a sample the simulation did not give (diverged, refused, not reached)
FAILED_RESIDUAL = 1.0


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
    range ``scale`` times the shift of the simulated puncture counted in scored samples (0 for a
    puncture the simulation has no match for). See the module docstring."""
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
        shifts[k] = (data.drop_n / scale) * (sim.travel_m - data.travel_m) / spacing
    return error, shifts


class Objective:
    """Residuals of the fitted trials for parameter vectors (see the module docstring)."""

    def __init__(self, trials, scene, keys, *, sets_spec=None, align='contact', gap_m=None, tick_s=0.01,
                 points_per_trial=200, phase_weights=None, keep_time_step_s=None, max_mass_scaling=None,
                 store=None, log_path=None, workers=None, scheduler=None, pool=None):
        from tissue_sim_ros.analysis.compare import plan_simulations
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
        self._cache: dict = {}
        self._points = None              # per trial: (sample indices, phases there)
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
        from tissue_sim_ros.analysis.calibration_parameters import overrides_for
        from tissue_sim_ros.engine.scene_overrides import apply_overrides
        return apply_overrides(self.base_spec, overrides_for(self.keys, [k.value(x) for k, x in zip(self.keys, u)]))

    def jobs_for(self, u) -> list:
        spec = self.spec_for(u)
        return [replace(job, scene_spec=spec, keep_time_step_s=self.keep_time_step_s,
                        max_mass_scaling=self.max_mass_scaling) for job in self.plan.jobs]

    # -- evaluation ---------------------------------------------------------------------------------
    @staticmethod
    def _key(u) -> tuple:
        return tuple(round(float(x), 12) for x in u)

    def evaluate_many(self, us) -> list[Evaluation]:
        """The evaluations of the vectors ``us``: their simulations in one parallel batch (those
        already run or stored are reused)."""
        from tissue_sim_ros.analysis.job_runner import run_jobs
        from tissue_sim_ros.analysis.trial_simulation import simulate
        keys = [self._key(u) for u in us]
        new = list(dict.fromkeys(k for k in keys if k not in self._cache))
        if new and self.budget is not None and len(self._cache) + len(new) > self.budget:
            raise BudgetSpent(f'{self.budget} evaluations spent')
        jobs = [job for k in new for job in self.jobs_for(k)]
        results = [self.store.get(job.key) if self.store is not None else None for job in jobs]
        todo = [i for i, r in enumerate(results) if r is None]

        def keep(position, result):
            results[todo[position]] = result
            if self.store is not None:
                self.store.put(jobs[todo[position]].key, result)
        run_jobs(simulate, [jobs[i] for i in todo], workers=self.workers, scheduler=self.scheduler,
                 on_result=keep, quiet=True, pool=self.pool)
        self.simulations_run += len(todo)
        per = len(self.plan.jobs)
        for n, k in enumerate(new):
            evaluation = self._score(k, results[n * per:(n + 1) * per])
            self._cache[k] = evaluation
            self._log(evaluation)
            if self.best is None or evaluation.objective < self.best.objective:
                self.best = evaluation
            if self.on_evaluation is not None:
                self.on_evaluation(evaluation)
        return [self._cache[k] for k in keys]

    def evaluate(self, u) -> Evaluation:
        return self.evaluate_many([u])[0]

    def _score(self, u, results) -> Evaluation:
        from tissue_sim_ros.analysis.compare import compare_trial, simulated_curve
        plan = self.plan
        curves = [simulated_curve(results[j], plan.schedules[j], plan.motions[plan.representative[j]],
                                  self.scene_gap_m) for j in range(len(plan.jobs))]
        comparisons = [compare_trial(trial, plan.motions[i], curves[plan.job_of_trial[i]], self.align)
                       for i, trial in enumerate(self.trials)]
        if self._points is None:
            self._points = [self._choose_points(c) for c in comparisons]
        failures = sorted({r.diverged for r in results if r.diverged})
        residuals = np.concatenate([self._trial_residuals(c, *points)
                                    for c, points in zip(comparisons, self._points)])
        return Evaluation(u, self.values(u), residuals, comparisons, list(results), failures)

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
        from tissue_sim_ros.analysis.compare import away_from_events
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
        record = {'time': time.strftime('%Y-%m-%dT%H:%M:%S'), 'values': evaluation.values,
                  'objective': evaluation.objective, 'nrmse_mean': evaluation.nrmse_mean,
                  'failures': evaluation.failures,
                  'mass_scaling': max((r.mass_scaling for r in evaluation.results), default=float('nan'))}
        with self.log_path.open('a') as log:
            log.write(json.dumps(record, default=float) + '\n')
