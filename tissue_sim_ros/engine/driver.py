"""The one simulation driver: a scene advanced to needle poses, with the health policy.

Every caller that runs a simulation (the node, ``tissue-sim insert``, and the replay, compare,
calibrate and predict commands) advances a :class:`SimulationDriver`; none steps the scene or
checks its health itself. The driver owns:

- the simulated clock: the scene's running target time (``Scene.advance`` steps whole substeps
  toward it, so successive calls add up); ``simulated_s`` counts the time advanced since start,
  resets included, for real-time factors;
- the needle pose in: a pose the engine refuses (``PoseError``: a jump over the limit, a
  pose inside the tissue at start) holds the needle where it is for that advance, counted;
- the finiteness and divergence policy: after every advance the reaction wrench must be finite
  and every displacement must fit a float32 (the node's point cloud), else the advance counts as
  a divergence, as does ``SimulationDiverged`` from the solver's watchdog. ``on_divergence``:
  ``'reset'`` (tissue to rest, needle to its initial pose), ``'hold'`` (frozen until
  :meth:`reset`; the last finite wrench stays) or ``'raise'`` (offline commands: the error
  reaches the caller);
- the last finite wrench and the deformed positions, in arrays allocated once; with several
  needles (``scene.needles``) one wrench per needle (``forces``, ``torques``; ``force`` and
  ``torque`` are the first needle's), ``others`` giving the other needles' poses;
- the estimate of the force error the mass scaling adds (``inertia``, an
  :class:`~tissue_sim_ros.engine.solver.inertia_estimate.InertiaEstimate` on the first needle's axis,
  updated after every advance, restarted by a reset), which every run reports.

A pose schedule (times, positions, orientations) is followed by :meth:`follow`, which samples the
wrench at each waypoint: the form the insertion, replay and prediction commands use.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tissue_sim_ros.engine.solver.inertia_estimate import InertiaEstimate
from tissue_sim_ros.engine.warm_up import warm_up
from tissue_sim_ros.errors import PoseError, SimulationDiverged

__all__ = ['ON_DIVERGENCE', 'AdvanceOutcome', 'SimulationDriver', 'Samples']

ON_DIVERGENCE = ('reset', 'hold', 'raise')
_FLOAT32_MAX = float(np.finfo(np.float32).max)


@dataclass
class AdvanceOutcome:
    """What one :meth:`SimulationDriver.advance` did: substeps run, the refusal of the pose (the
    needle was held instead), the divergence (handled by the policy). Callers log from it."""

    substeps: int = 0
    refused: PoseError | None = None
    diverged: SimulationDiverged | None = None


@dataclass
class Samples:
    """The wrench and needle state at each waypoint of a followed schedule (world frame unless
    the driver's ``wrench_frame`` says 'needle')."""

    time: np.ndarray        # (k,) s, simulated time at the sample
    force: np.ndarray       # (k, 3) N, the tissue on the needle
    torque: np.ndarray      # (k, 3) N m, about the needle base origin
    tip_depth: np.ndarray   # (k,) m below the entry point, 0 outside
    phase: list             # (k,) str
    substeps: int
    tip: np.ndarray = None              # (k, 3) m, the tip's apex, world frame
    tip_deflection: np.ndarray = None   # (k,) m, the tip's distance from the base frame's axis


class SimulationDriver:
    """A scene driven by needle poses (see the module docstring)."""

    def __init__(self, scene, *, wrench_frame: str = 'world', on_divergence: str = 'raise'):
        if wrench_frame not in ('world', 'needle'):
            raise ValueError(f"wrench_frame = {wrench_frame!r}: expected 'world' or 'needle'")
        if on_divergence not in ON_DIVERGENCE:
            raise ValueError(f'on_divergence = {on_divergence!r}: expected one of {ON_DIVERGENCE}')
        # the needles' kernels compiled before the first advance
        warm_up(flexible=any(n.rod is not None for n in scene.needles))
        self.scene = scene
        self.wrench_frame = wrench_frame
        self.on_divergence = on_divergence
        self.held = False          # diverged with on_divergence = 'hold'
        self.divergences = 0
        self.refusals = 0
        self.simulated_s = 0.0     # time advanced since start; resets do not rewind it
        self.dropped_s = 0.0       # time asked for and dropped by drop_lag
        self.forces = np.zeros((len(scene.needles), 3))   # the last finite wrench of each needle
        self.torques = np.zeros((len(scene.needles), 3))
        self.force, self.torque = self.forces[0], self.torques[0]   # the first needle's (views)
        self._deformed = np.empty_like(scene.rest_positions)
        self.inertia = InertiaEstimate()
        self._take_finite_wrenches()         # a scene given mid-run: its wrench from the start
        self._update_inertia(0.0)

    # -- the clock ---------------------------------------------------------------------------

    @property
    def time(self) -> float:
        """Simulated time of the state [s] (since the last reset)."""
        return float(self.scene.time)

    @property
    def target_time(self) -> float:
        """The running target [s]: the sum of the durations asked for since reset."""
        return float(self.scene.target_time)

    @property
    def dt(self) -> float:
        return float(self.scene.dt)

    @property
    def lag_s(self) -> float:
        """Simulated time asked for but not yet simulated [s] (what deadlines left)."""
        return max(0.0, self.scene.target_time - self.scene.time)

    def drop_lag(self, max_lag_s: float) -> float:
        """Keep the lag at most ``max_lag_s``: the excess is dropped (counted in ``dropped_s``);
        returns what was dropped now."""
        dropped = self.scene.drop_behind(max_lag_s)
        self.dropped_s += dropped
        return dropped

    @property
    def behind(self) -> bool:
        """A deadline left whole substeps for a later call (``advance(0)`` runs them)."""
        return self.scene.time + self.scene.dt <= self.scene.target_time

    # -- advancing ---------------------------------------------------------------------------

    def advance(self, duration: float, position=None, orientation=None, *, deadline=None,
                max_steps=None, others=None) -> AdvanceOutcome:
        """Advance ``duration`` [s] with the needle moving linearly to the pose (None: held where
        it is); ``deadline``/``max_steps``/``others`` (the other needles' poses) as in
        ``Scene.advance``. A refused pose holds every needle for the advance. Applies the policy;
        with ``on_divergence='raise'`` a divergence raises SimulationDiverged."""
        outcome = AdvanceOutcome()
        if self.held:
            return outcome
        scene = self.scene
        if position is None or orientation is None:
            position, orientation = scene.needle_pose
        start = scene.time
        try:
            try:
                outcome.substeps = scene.advance(duration, position, orientation, deadline, max_steps, others)
            except PoseError as exc:
                self.refusals += 1
                outcome.refused = exc
                hold_position, hold_orientation = scene.needle_pose
                outcome.substeps = scene.advance(duration, hold_position, hold_orientation,
                                                 deadline, max_steps)
            self.take_state()
            self.simulated_s += duration
            self._update_inertia(scene.time - start)
        except SimulationDiverged as exc:
            outcome.diverged = exc
            self._diverged(exc)
        return outcome

    def follow(self, times, positions, orientations=None, *, progress=None) -> Samples:
        """Follow a pose schedule: from the current pose, to ``positions[k]`` (orientation
        ``orientations[k]``, default the current one) at simulated time ``times[k]`` (from now,
        increasing), sampling the wrench at each. ``progress(k, driver)``: called after waypoint
        k (None: quiet). A refused pose raises PoseError: a schedule is the caller's."""
        times = np.asarray(times, dtype=np.float64)
        positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        if times.ndim != 1 or times.size != positions.shape[0] or times.size == 0:
            raise ValueError(f'times: {times.shape} against positions {positions.shape}: expected '
                             'one time per pose, at least one')
        if not np.all(np.isfinite(times)) or np.any(np.diff(times) < 0) or times[0] < 0:
            raise ValueError('times: expected finite times >= 0 that do not decrease')
        if orientations is None:
            orientations = np.repeat(self.scene.needle_pose[1][None, :], times.size, axis=0)
        orientations = np.asarray(orientations, dtype=np.float64).reshape(-1, 4)
        k = times.size
        force, torque = np.empty((k, 3)), np.empty((k, 3))
        when, depth, phase = np.empty(k), np.empty(k), []
        tip, deflection = np.empty((k, 3)), np.empty(k)
        substeps, previous = 0, 0.0
        for i in range(k):
            outcome = self.advance(times[i] - previous, positions[i], orientations[i])
            previous = times[i]
            substeps += outcome.substeps
            if outcome.refused is not None:
                raise outcome.refused
            force[i], torque[i] = self.force, self.torque
            when[i], depth[i] = self.scene.time, self.scene.tip_depth
            tip[i], deflection[i] = self.scene.needle.tip, self.scene.tip_deflection
            phase.append(str(self.scene.phase))
            if progress is not None:
                progress(i, self)
        return Samples(when, force, torque, depth, phase, substeps, tip, deflection)

    def take_state(self) -> None:
        """Take the wrench of the scene's state as it is (after an advance, or of a scene copied
        mid-run), or raise SimulationDiverged for a non-finite wrench or a displacement that does
        not fit a float32. Changes nothing in the scene."""
        scene = self.scene
        wrenches = [scene.reaction_wrench(self.wrench_frame, k) for k in range(len(scene.needles))]
        for force, torque in wrenches:
            if not all(map(math.isfinite, force.tolist() + torque.tolist())):
                raise SimulationDiverged(
                    f'non-finite reaction wrench {np.asarray(force).tolist()} {np.asarray(torque).tolist()}',
                    scene.simulation.step_count, float(scene.time), float(scene.dt), float('nan'))
        displacement = scene.displacement           # the largest |u| without an |u| array (NaN stays NaN)
        largest = max(float(displacement.max(initial=0.0)), -float(displacement.min(initial=0.0)))
        if not largest < _FLOAT32_MAX:
            raise SimulationDiverged(f'displacement {largest:.3g} m does not fit a float32',
                                     scene.simulation.step_count, float(scene.time),
                                     float(scene.dt), float('nan'))
        for k, (force, torque) in enumerate(wrenches):
            self.forces[k], self.torques[k] = force, torque

    def _diverged(self, exc: SimulationDiverged) -> None:
        self.divergences += 1
        if self.on_divergence == 'raise':
            raise exc
        if self.on_divergence == 'reset':
            self.reset()
        else:
            self.held = True

    def reset(self) -> None:
        """Tissue at rest, needle at its initial pose, time 0, held cleared; the wrench is the
        rest state's (zeros if that is not finite: never a NaN out of a reset)."""
        self.scene.reset()
        self.held = False
        self._take_finite_wrenches()
        self.inertia.reset()
        self._update_inertia(0.0)

    def place_needle(self, position, orientation) -> None:
        """The first needle starts at this pose from now on (``Scene.place_needle``; PoseError when
        it touches the tissue or the pose lies inside it); its wrench is then the state's."""
        self.scene.place_needle(position, orientation)
        self._take_finite_wrenches()
        self.inertia.reset()
        self._update_inertia(0.0)

    def _update_inertia(self, elapsed: float) -> None:
        needle = self.scene.needle
        axis = needle.axis
        self.inertia.update(self.scene.simulation, elapsed, axis,
                            -float(np.dot(needle.wrench_force, axis)), len(needle.puncture_events))

    def _take_finite_wrenches(self) -> None:
        """Each needle's wrench of the state as it is, zeros where it is not finite."""
        for k in range(len(self.scene.needles)):
            force, torque = self.scene.reaction_wrench(self.wrench_frame, k)
            finite = np.all(np.isfinite(force)) and np.all(np.isfinite(torque))
            self.forces[k] = force if finite else 0.0
            self.torques[k] = torque if finite else 0.0

    # -- state -------------------------------------------------------------------------------

    @property
    def wrench(self):
        """(force, torque) of the last finite state [N, N m]; the driver's own arrays."""
        return self.force, self.torque

    def deformed_positions(self) -> np.ndarray:
        """Rest positions plus displacement, in an array reused between calls (its shape follows
        the mesh)."""
        rest = self.scene.rest_positions
        if self._deformed.shape != rest.shape:
            self._deformed = np.empty_like(rest)
        np.add(rest, self.scene.displacement, out=self._deformed)
        return self._deformed

    @property
    def displacement(self) -> np.ndarray:
        return self.scene.displacement

    @property
    def needle_pose(self):
        return self.scene.needle_pose

    def real_time_factor(self, wall_s: float) -> float:
        return self.simulated_s / wall_s if wall_s > 0 else math.inf
