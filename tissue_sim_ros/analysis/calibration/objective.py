"""The calibration's objective: the comparison's residuals of every fitted trial, as one vector.

A parameter vector (unit coordinates, :mod:`~tissue_sim_ros.analysis.calibration.parameters`)
becomes one simulation per speed of the study (the comparison's plan: the median repeat's
measured motion, :func:`~tissue_sim_ros.analysis.compare.compare.plan_simulations`; with
``per_repeat``, one per trial, its regions moved by its own offsets: :mod:`.repeat_draws`), and
each trial is compared with its simulation by :func:`~tissue_sim_ros.analysis.compare.compare.
compare_trial`, the same comparison ``tissue-sim compare`` reports. The residuals of a trial are the simulated
minus the measured force at fixed samples (chosen once: evenly over the compared part of the
trial, at most ``points_per_trial``), divided by the trial's force range (so each residual is an
NRMSE contribution) and by the square root of the number of residuals, times the weight of the
sample's phase: the sum of squares is the mean squared NRMSE of the trials. Samples at a
puncture of either curve count 0, as compare's NRMSE leaves them out (a one-sample difference in
when the force drops would dominate the sum); the puncture stage fits the events themselves.

A simulated puncture later (or earlier) than the measured one puts the samples between the two
on opposite sides of the drop, each missing by the drop, their count a staircase in the
parameters that no finite difference reads. So those samples count 0 too, and each measured
puncture adds one residual: the measured drop over the force range times the signed root of the
Huber cost of the matched simulated puncture's shift (the same layer's) counted in scored samples,
with the inserted phase's weight (:func:`huber_root`): the shift's square within half a sample,
one sample's cost per sample beyond, as the samples it replaces would (growing as the square all
the way, the search would trade the curve for the puncture's depth).

A run that diverges, trips the watchdog, or whose keys the scene refuses, scores 1 at every
residual (a miss by the whole force range: worse than any run that finishes) and its reason is
logged; a sample the simulation did not reach scores 1 likewise. The samples are chosen among
those the first finished run reached, and the plan's simulations run past the end of every repeat
they are compared with (:mod:`~tissue_sim_ros.analysis.compare.measured_motion`), so a miss is a
run's, not the data's: a sample no run reaches would be a constant in every evaluation, which
stops the search's relative tests early. Nothing is NaN and nothing stops the search.

A stage of the search that fits only the first phases of the curve (the loading before the first
puncture, the puncture itself, the steady insertion, the pause) needs the simulations only that
far: an evaluation for ``phases`` runs each speed's simulation to a **horizon**, the latest sample
of those phases over the speed's trials (each on its own contact's clock; for a layer's puncture,
the travel to ``EVENT_REACH`` times its depth, and the detector's window at least, so that a
simulated puncture somewhat deeper than the measured one is still found, or the insertion's end
when that reach lies deeper than the needle goes) plus ``HORIZON_MARGIN_S``
and ``HORIZON_MARGIN_FRACTION`` of it (the simulated contact's lag, the cross-correlation's
shift). On the calibration benchmark the loading ends at a quarter of the slowest speed's run.
Such a partial evaluation scores only its phases (its other samples are misses), so it never
becomes the best; one that does not reach a sample of its phases is run again whole.

The data's punctures are those its repeats share (``compare.measured_layers``: a pre-drop is no
puncture, and each carries its layer), and a simulated puncture
is paired with the data's of the same layer; the samples between them count 0 (as above) and, in
compare's NRMSE, too when the simulated one lies within the repeats' spread. Each sample carries
its stage label (:func:`~tissue_sim_ros.analysis.calibration.stages.sample_labels`): a stage's
residuals are those of its labels, and its puncture events (per layer, the force and depth
errors), and its horizon the latest of those samples (a puncture's: its depth plus half of it,
and the detector's window, at least).

**The budget** (:class:`Budget`, one for a whole calibration, coarse and fine scenes alike):
every evaluation the search asks for counts, whether its simulations run or are replayed from
the store (a resumed run counts what it replays, so it ends where the uninterrupted one did), a
partial evaluation run again whole counts twice; a batch that would pass the limit is not run
(:class:`BudgetSpent`).

Every evaluation is appended to ``evaluations.jsonl`` once, across resumes (parameter values,
objective and mean NRMSE, or for a partial one its stage's objective, failures, ``run``: the run of the study that made it, 1 the first,
``elapsed_s``: the seconds since that run began, ``replayed``: its simulations all came from the
store); the simulations are kept in a :class:`~tissue_sim_ros.analysis.compare.trial_simulation.ResultStore`,
so a second run over the same inputs replays them instead of simulating again (resume).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from tissue_sim_ros.analysis.calibration.evaluation_log import log_evaluation, logged_keys

__all__ = ['Budget', 'Evaluation', 'Objective', 'FAILED_RESIDUAL', 'BudgetSpent', 'calibrated_spec', 'huber_root',
           'puncture_shift_residuals']

#: the residual of a sample the simulation did not give (diverged, refused, not reached)
FAILED_RESIDUAL = 1.0
#: the puncture stage's simulations run to this multiple of the first puncture's depth
EVENT_REACH = 1.5
#: a horizon's margin: this much time, and this fraction of the time since contact
HORIZON_MARGIN_S = 0.5
HORIZON_MARGIN_FRACTION = 0.05


class BudgetSpent(Exception):
    """The evaluations the search may run are spent (``Objective.budget``)."""


class Budget:
    """Evaluations a calibration may make (``limit``; None: no limit), ``used`` so far (run or
    replayed), ``replayed`` of them; ``reserve``: kept back from the search for its result's checks."""

    def __init__(self, limit: int | None = None, reserve: int = 0):
        self.limit, self.reserve, self.used, self.replayed = limit, int(reserve), 0, 0

    def left(self, for_search: bool = True) -> float:
        if self.limit is None:
            return float('inf')
        return self.limit - self.used - (self.reserve if for_search else 0)

    def take(self, count: int, for_search: bool = True) -> None:
        """Count ``count`` evaluations, or raise BudgetSpent when they would pass the limit."""
        if count > self.left(for_search):
            raise BudgetSpent(f'{self.limit} evaluations: {self.used} used'
                              + (f', {self.reserve} kept for the standard errors' if for_search and self.reserve else ''))
        self.used += count


@dataclass
class Evaluation:
    """One parameter vector's outcome."""

    u: tuple
    values: dict
    residuals: np.ndarray
    comparisons: list
    results: list
    failures: list = field(default_factory=list)
    phases: object = None      # the phases a partial evaluation ran for (module docstring); None: whole
    replayed: bool = False     # every simulation came from the store (an earlier run's)
    trial_sizes: tuple = ()    # per trial, how many of ``residuals`` are its (in order)
    draws: int = 0             # the set of repeat offsets it ran with (one more each time they are set)

    def trial_objectives(self) -> np.ndarray:
        """Each trial's part of the objective (its residuals' sum of squares), in trial order."""
        ends = np.cumsum((0,) + tuple(self.trial_sizes))
        return np.array([float(self.residuals[a:b] @ self.residuals[a:b]) for a, b in zip(ends[:-1], ends[1:])])

    @property
    def objective(self) -> float:
        return float(self.residuals @ self.residuals)

    @property
    def nrmse_mean(self) -> float:
        scores = [c.errors.get('nrmse', np.nan) for c in self.comparisons]
        return float(np.nanmean(scores)) if np.isfinite(scores).any() else float('nan')


def puncture_shift_residuals(comparison, indices, error, scale):
    """``error`` (a trial's residuals at the scored samples ``indices``) with the samples strictly
    between each measured puncture and the simulated one of its layer set to 0, and per measured
    puncture its shift as one residual: the measured drop over the force range ``scale`` times the
    Huber root of the shift counted in scored samples; a puncture the simulation lacks costs as one
    shifted past every scored sample up to the next measured puncture (or the end), so a run that
    stops puncturing a layer is not let off the samples the missing drop leaves on the wrong side."""
    travel = comparison.travel_since_contact_m
    spacing = np.diff(travel[indices])
    spacing = float(np.median(spacing[spacing > 0])) if np.any(spacing > 0) else 0.0
    shifts = np.zeros(len(comparison.measured_punctures))
    if spacing <= 0:
        return error, shifts
    from tissue_sim_ros.analysis.compare.shared_punctures import pair_punctures
    error = np.array(error, dtype=float)
    paired = {id(m): sim for m, sim in pair_punctures(comparison.measured_punctures, comparison.simulated_punctures)}
    measured = comparison.measured_punctures
    for k, data in enumerate(measured):
        sim = paired.get(id(data))
        if sim is None:
            until = measured[k + 1].index if k + 1 < len(measured) else np.inf
            missed = int(np.count_nonzero((indices > data.index) & (indices < until)))
            shifts[k] = (data.drop_n / scale) * huber_root(max(missed, 1))
            continue
        first, last = sorted((data.index, sim.index))
        error[(indices > first) & (indices <= last)] = 0.0   # both peaks are the last samples before a drop
        shifts[k] = (data.drop_n / scale) * huber_root((sim.travel_m - data.travel_m) / spacing)
    return error, shifts


def huber_root(samples):
    """The signed root of the Huber cost of a shift counted in samples: samples^2 up to half a
    sample, |samples| - 1/4 beyond (continuous with its slope; one sample's cost per sample)."""
    samples = np.asarray(samples, dtype=float)
    cost = np.where(np.abs(samples) <= 0.5, samples * samples, np.abs(samples) - 0.25)
    return np.sign(samples) * np.sqrt(cost)


class Objective:
    """Residuals of the fitted trials for parameter vectors (see the module docstring)."""

    def __init__(self, trials, scene, keys, *, sets_spec=None, align='contact', gap_m=None, tick_s=0.01,
                 points_per_trial=200, phase_weights=None, keep_time_step_s=None, max_mass_scaling=None,
                 store=None, log_path=None, workers=None, scheduler=None, pool=None, per_repeat=False):
        from tissue_sim_ros.analysis.compare.compare import plan_simulations
        self.trials, self.keys, self.align = list(trials), list(keys), align
        self.base_spec = sets_spec if sets_spec is not None else scene.spec
        self.base_dir = str(scene.base_dir)
        self.scene_gap_m = scene.start_gap_m
        self.plan = plan_simulations(self.trials, scene, gap_m=gap_m, tick_s=tick_s, per_trial=per_repeat)
        #: per trial {region: (rupture force [N], depth [m]) offsets} (repeat_draws); None: the scene's
        self.repeat_offsets, self.draws = ([{} for _ in self.trials] if per_repeat else None), 0
        self.points_per_trial = int(points_per_trial)
        self.phase_weights = dict(phase_weights or {})
        self.keep_time_step_s, self.max_mass_scaling = keep_time_step_s, max_mass_scaling
        self.store, self.workers, self.scheduler, self.pool = store, workers, scheduler, pool
        self.log_path = None if log_path is None else Path(log_path)
        self._logged, self.run_number = logged_keys(self.log_path)       # a resumed run logs each evaluation once
        self.started = time.perf_counter()
        from tissue_sim_ros.analysis.compare.compare import measured_layers
        self._measured, self._layers = measured_layers(self.trials, self.plan.motions)
        self.n_layers = max((len(layers) for layers in self._layers if layers), default=0)
        self.regions = self.base_spec['regions']
        self._cache: dict = {}           # (vector key, horizon key) -> Evaluation; horizon None: whole
        self._points = None              # per trial: (sample indices, phases there, stage labels there)
        self._horizons: dict = {}        # stage phases -> per job the schedule's end index (None: whole)
        self.simulations_run = 0
        self.best: Evaluation | None = None
        self.on_evaluation = None        # called with each new Evaluation (progress)
        self.budget: Budget | None = None   # the calibration's (None: no limit), else BudgetSpent
        self.for_search = True           # whether the budget's reserve is kept back

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
        from tissue_sim_ros.engine.scene.variation import moved_regions
        spec = self.spec_for(u)
        ends = ends or [None] * len(self.plan.jobs)
        specs = [spec if self.repeat_offsets is None else
                 {**spec, 'regions': moved_regions(spec['regions'], self.repeat_offsets[self.plan.representative[j]])}
                 for j in range(len(self.plan.jobs))]
        return [replace(job, scene_spec=spec, keep_time_step_s=self.keep_time_step_s,
                        max_mass_scaling=self.max_mass_scaling, times_s=job.times_s[:end],
                        positions=job.positions[:end])
                for job, spec, end in zip(self.plan.jobs, specs, ends)]

    def set_repeat_offsets(self, offsets) -> None:
        """Each repeat's offsets (per trial); earlier evaluations no longer hold, nor the best."""
        self.repeat_offsets = [dict(o) for o in offsets]
        self._cache, self.best, self.draws = {}, None, self.draws + 1

    # -- horizons -----------------------------------------------------------------------------------
    def horizon(self, phases):
        """Per job, the schedule's end index an evaluation for ``phases`` needs (module docstring),
        or None when it needs the whole curves; known after the first (whole) evaluation."""
        if phases is None or self._points is None:
            return None
        labels, events = self._scope(phases)
        key = (labels, events)
        if key not in self._horizons:
            self._horizons[key] = self._find_horizon(labels, events)
        return self._horizons[key]

    def _scope(self, phases) -> tuple:
        """(sample labels, event layers) of a stage: a Stage, 'events' (every layer's puncture), or
        compare's phase names ('loading': the segments before a puncture, 'inserted': after the last)."""
        from tissue_sim_ros.analysis.calibration.stages import Stage
        if isinstance(phases, Stage):
            return tuple(sorted(phases.labels)), tuple(phases.events)
        if phases == 'events':
            return (), tuple(range(max(self.n_layers, 1)))
        names = (phases,) if isinstance(phases, str) else tuple(phases)
        labels = set()
        segments = max(self.n_layers, 1)
        for name in names:
            if name == 'loading':
                labels |= {f'segment {k}' for k in range(segments)}
            elif name == 'inserted':
                labels.add(f'segment {self.n_layers}')
            elif name == 'retraction':
                labels |= {f'retraction {k}' for k in range(segments)}
            else:
                labels.add(name)
        return tuple(sorted(labels)), ()

    def _find_horizon(self, labels, events):
        from tissue_sim_ros.analysis.compare.force_events import PUNCTURE_WINDOW_M
        if not all(label.startswith('segment ') or label == 'hold' for label in labels):
            return None
        needed = [0.0] * len(self.plan.jobs)           # per job: time since contact
        for i, (comparison, (indices, _, sample_labels)) in enumerate(zip(self._first_comparisons, self._points)):
            since = comparison.time_since_contact_s
            times = [float(since[inside].max()) for inside in [indices[np.isin(sample_labels, labels)]] if inside.size]
            for layer in events:
                punctures = [p for p in comparison.measured_punctures if p.layer == layer]
                if not punctures:
                    continue
                depth = punctures[0].travel_m
                reach = depth + max(PUNCTURE_WINDOW_M, (EVENT_REACH - 1.0) * depth)
                travel = comparison.travel_since_contact_m
                beyond = np.flatnonzero(travel >= reach)
                # a reach past the deepest travel: the insertion's end (no puncture comes later)
                times.append(float(since[beyond[0] if beyond.size else int(np.argmax(travel))]))
            if not times:
                continue
            job = self.plan.job_of_trial[i]
            needed[job] = max(needed[job], max(times))
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
        scope_key = None if scope is None else str(self._scope(scope))
        keys = [self._key(u) for u in us]
        found = {k: self._cache.get((k, None)) or self._cache.get((k, scope_key)) for k in keys}
        new = list(dict.fromkeys(k for k in keys if found[k] is None))
        if new and self.budget is not None:
            self.budget.take(len(new), self.for_search)
        for k, evaluation in zip(new, self._run(new, ends, scope)):
            if scope is not None and self._short_of(evaluation, phases):
                if self.budget is not None:
                    self.budget.take(1, self.for_search)
                evaluation = self._run([k], None, None)[0]        # the horizon fell short: whole
            found[k] = self._cache[(k, None if evaluation.phases is None else scope_key)] = evaluation
            if self.budget is not None and evaluation.replayed:
                self.budget.replayed += 1
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
        jobs, results, stored = [], [], []
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
        stored = [all(results[n * len(self.plan.jobs) + j] is not None for j in range(len(self.plan.jobs)))
                  and jobs[n * len(self.plan.jobs)] is not None for n in range(len(vectors))]

        def keep(position, result):
            results[todo[position]] = result
            if self.store is not None:
                self.store.put(jobs[todo[position]].key, result)
        run_jobs(simulate, [jobs[i] for i in todo], workers=self.workers, scheduler=self.scheduler,
                 on_result=keep, quiet=True, pool=self.pool)
        self.simulations_run += len(todo)
        per = len(self.plan.jobs)
        scored = [self._score(k, results[n * per:(n + 1) * per], ends, phases) for n, k in enumerate(vectors)]
        for evaluation, replayed in zip(scored, stored):
            evaluation.replayed = replayed
        return scored

    def _short_of(self, evaluation: Evaluation, phases) -> bool:
        """Whether a partial evaluation left a sample of ``phases`` unreached (not diverged; a
        puncture beyond the reach is a miss, not a shortfall)."""
        labels, _ = self._scope(phases)
        if evaluation.failures or not labels:
            return False
        return any(np.any(np.isnan(c.simulated_n[indices[np.isin(sample_labels, labels)]]))
                   for c, (indices, _, sample_labels) in zip(evaluation.comparisons, self._points))

    def evaluate(self, u, phases=None) -> Evaluation:
        return self.evaluate_many([u], phases)[0]

    def _score(self, u, results, ends=None, phases=None) -> Evaluation:
        from tissue_sim_ros.analysis.compare.compare import compare_trial, simulated_curve
        plan = self.plan
        ends = ends or [None] * len(plan.jobs)
        curves = [simulated_curve(results[j], _cut(plan.schedules[j], ends[j]), plan.motions[plan.representative[j]],
                                  self.scene_gap_m) for j in range(len(plan.jobs))]
        comparisons = [compare_trial(trial, plan.motions[i], curves[plan.job_of_trial[i]], self.align,
                                     measured_punctures=self._measured[i], layers=self._layers[i])
                       for i, trial in enumerate(self.trials)]
        if self._points is None:     # the first evaluation (whole) chooses the points
            self._points, self._first_comparisons = [self._choose_points(c) for c in comparisons], comparisons
        failures = sorted({r.diverged for r in results if r.diverged})
        per_trial = [self._trial_residuals(c, *points) for c, points in zip(comparisons, self._points)]
        return Evaluation(u, self.values(u), np.concatenate(per_trial), comparisons, list(results), failures,
                          None if all(end is None for end in ends) else phases,
                          trial_sizes=tuple(len(r) for r in per_trial), draws=self.draws)

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
        from tissue_sim_ros.analysis.calibration.stages import sample_labels
        candidates = np.flatnonzero(eligible)
        if candidates.size > self.points_per_trial:
            candidates = candidates[np.linspace(0, candidates.size - 1, self.points_per_trial).round().astype(int)]
        labels = sample_labels(comparison.travel_since_contact_m, phases, comparison.measured_punctures)
        return candidates, phases[candidates], labels[candidates]

    def _trial_residuals(self, comparison, indices, phases, labels=None) -> np.ndarray:
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
        """The residuals a stage of the search fits (None: all): those of the samples its labels
        hold (:meth:`_scope`), then per trial and per layer of its events the layer's puncture:
        its force error over the trial's force range and its depth error over the trial's travel
        range (a simulation without that layer's puncture scores 1 on both), scaled when a stage
        has both so that each group weighs as the mean of its squared relative errors.""" 
        from tissue_sim_ros.analysis.compare.shared_punctures import pair_punctures
        if phases is None:
            return evaluation.residuals
        labels, events = self._scope(phases)
        mask = np.concatenate([np.concatenate([np.isin(sample_labels, labels),
                                               np.zeros(len(c.measured_punctures), bool)])
                               for (_, _, sample_labels), c in zip(self._points, evaluation.comparisons)])
        samples = evaluation.residuals[mask]
        out = []
        for c in evaluation.comparisons:
            pairs = {m.layer: s for m, s in pair_punctures(c.measured_punctures, c.simulated_punctures)}
            for m in c.measured_punctures:
                if m.layer not in events:
                    continue
                sim = pairs.get(m.layer) if not c.diverged else None
                if sim is None:
                    out.append(np.array([FAILED_RESIDUAL, FAILED_RESIDUAL]))
                    continue
                out.append(np.array([(sim.force_n - m.force_n) / (float(np.ptp(c.measured_n)) or 1.0),
                                     (sim.travel_m - m.travel_m) / (float(np.ptp(c.travel_since_contact_m)) or 1.0)]))
        if not out:
            return samples
        events_part = np.concatenate(out)
        if samples.size:          # each group a mean of squared relative errors, weighted alike
            total = sum(len(points[0]) for points in self._points)
            events_part = events_part * np.sqrt(samples.size / (events_part.size * max(total, 1)))
        return np.concatenate([samples, events_part])

    def _log(self, evaluation: Evaluation) -> None:
        if self.log_path is not None:
            stage = None if evaluation.phases is None else self.stage_residuals(evaluation, evaluation.phases)
            log_evaluation(self.log_path, self._logged, evaluation, stage, run=self.run_number,
                           elapsed_s=time.perf_counter() - self.started)

def _cut(schedule, end):
    """``schedule`` up to its sample ``end`` (None: whole)."""
    if end is None:
        return schedule
    return replace(schedule, times_s=schedule.times_s[:end], positions=schedule.positions[:end],
                   travel_m=schedule.travel_m[:end], trial_time_s=schedule.trial_time_s[:end])


def calibrated_spec(fit: dict) -> dict:
    """The scene keys of a calibration's optimum, with the mass scaling it ran with (and the
    damping rate that keeps the scene's damping force at it); fitted repeat by repeat, the mean
    repeat with the repeats' spread (``repeat_draws.folded_spec``)."""
    from tissue_sim_ros.analysis.calibration.repeat_draws import folded_spec
    from tissue_sim_ros.engine.scene.keys import with_mass_scaling
    spec = fit['objective'].spec_for(fit['u'])
    if fit.get('repeat_offsets'):         # each repeat simulated with its own draws: the mean repeat
        spec = folded_spec(spec, fit['repeat_offsets'])
    return with_mass_scaling(spec, fit['inertia']['mass_scaling_at_optimum'])
