"""One simulated trial: a scene driven along a pose schedule, as a job a worker process can run.

The comparison with load-cell data, the calibration and the speed-accuracy chart all run many
simulations of one scene (or of its variants) along measured or scripted motions. A
:class:`SimulationJob` is plain data (the scene's keys after overrides, the schedule), so it
pickles to a worker process or a Dask cluster; :func:`simulate` runs it through the one
:class:`~tissue_sim_ros.engine.driver.SimulationDriver` and returns plain arrays. A worker keeps
the scenes it built (by their keys' hash) and resets them between jobs instead of building them
again. A run that diverges, or whose keys the scene refuses, is a result too (``diverged``: the
reason), never an exception that would stop a whole study.

Each job runs on ``threads`` numba threads (default 1), set for the thread that runs it and
restored after. The simulations are the parallelism: a process pool's workers start with one
numba thread, but a Dask worker, or this process running a batch of one, has numba's whole pool
(every core), and simulations side by side on it fight over the cores, each parallel region's
threads spinning while the others wait (a Dask ``compare`` on 2 cores with 2 workers of one
thread each: 10x the process pool's time per simulation, not a compile: the workers load the
kernels from the per-user cache). Figures: docs/performance.md.

:class:`ResultStore` keeps every result in ``DIR/simulations/<key>.npz`` as it arrives, so an
interrupted study resumes where it stopped (the key hashes the job: scene keys and schedule).

Affordable stiffness (the calibration's rule): a job with ``keep_time_step_s`` raises the scene's
mass scaling when its parameters would shrink the time step below that step (the critical step
grows as the square root of the mass scaling, so the factor is (kept step / step)^2), at most to
``max_mass_scaling``, beyond which the step shrinks instead. The result records the mass scaling
and time step used.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ['SimulationJob', 'SimulationResult', 'simulate', 'ResultStore', 'job_key']


@dataclass(frozen=True)
class SimulationJob:
    """A scene (its keys after overrides, and the folder its mesh file is relative to) and the
    schedule it follows: times [s] from the start, needle base positions (k, 3) [m]."""

    scene_spec: dict
    base_dir: str
    times_s: np.ndarray
    positions: np.ndarray
    threads: int = 1
    keep_time_step_s: float | None = None
    max_mass_scaling: float | None = None

    @property
    def key(self) -> str:
        return job_key(self)


def job_key(job: SimulationJob) -> str:
    digest = hashlib.sha256(json.dumps(job.scene_spec, sort_keys=True, default=str).encode())
    digest.update(str(job.base_dir).encode())
    digest.update(np.ascontiguousarray(job.times_s, dtype=np.float64).tobytes())
    digest.update(np.ascontiguousarray(job.positions, dtype=np.float64).tobytes())
    if job.keep_time_step_s is not None:
        digest.update(f'{job.keep_time_step_s!r} {job.max_mass_scaling!r}'.encode())
    return digest.hexdigest()[:24]


@dataclass
class SimulationResult:
    """Per sample of the schedule: simulated time [s], the axial force [N] (positive while the
    tissue resists insertion), the tip depth below the entry point [m]; the punctures (travel
    of the tip from the start [m] and axial force [N] at each, and the layer each punctured: its
    region's place among the scene's regions with a membrane, the outer one 0); ``diverged``: the
    reason, or ''. ``wall_s``, ``steps``: what it cost; ``mass_scaling`` and ``time_step_s``: what it
    ran with."""

    time_s: np.ndarray
    axial_force_n: np.ndarray
    tip_depth_m: np.ndarray
    puncture_travel_m: np.ndarray
    puncture_force_n: np.ndarray
    diverged: str = ''
    wall_s: float = 0.0
    steps: int = 0
    mass_scaling: float = float('nan')
    time_step_s: float = float('nan')
    puncture_layer: np.ndarray = None

    def __post_init__(self):
        if self.puncture_layer is None:
            self.puncture_layer = np.full(len(self.puncture_travel_m), -1, dtype=np.int64)

    @classmethod
    def refused(cls, samples: int, reason) -> 'SimulationResult':
        """A run whose scene keys the scene refuses: a failed run (every force NaN), not a crash."""
        nan = np.full(samples, np.nan)
        return cls(nan, nan, nan, np.zeros(0), np.zeros(0), diverged=f'scene refused: {reason}')


_SCENES: dict = {}


def _scene(job: SimulationJob):
    from tissue_sim_ros.engine.scene.scene import Scene
    from tissue_sim_ros.engine.scene.keys import with_mass_scaling
    key = hashlib.sha256(json.dumps(job.scene_spec, sort_keys=True, default=str).encode()
                         + str(job.base_dir).encode()).hexdigest()
    scene = _SCENES.get(key)
    if scene is None:
        scene = Scene(job.scene_spec, base_dir=job.base_dir)
        if job.keep_time_step_s is not None and scene.dt < job.keep_time_step_s * (1 - 1e-9):
            scaling = scene.spec['solver']['mass_scaling'] * (job.keep_time_step_s / scene.dt) ** 2
            if job.max_mass_scaling is not None:
                scaling = min(scaling, job.max_mass_scaling)
            spec = with_mass_scaling(dict(job.scene_spec, solver=scene.spec['solver']), scaling)
            scene = Scene(spec, base_dir=job.base_dir)
        scene.model.set_threads(job.threads)
        _SCENES.clear()                 # one scene per worker at a time: memory
        _SCENES[key] = scene
    return scene


def simulate(job: SimulationJob) -> SimulationResult:
    """Run ``job`` (see the module docstring) on ``job.threads`` numba threads, set for the
    calling thread and restored after."""
    import numba
    previous = numba.get_num_threads()
    numba.set_num_threads(max(1, min(int(job.threads), numba.config.NUMBA_NUM_THREADS)))
    try:
        return _simulate(job)
    finally:
        numba.set_num_threads(previous)


def _simulate(job: SimulationJob) -> SimulationResult:
    import time

    from tissue_sim_ros.engine.driver import SimulationDriver
    from tissue_sim_ros.errors import InputError, SimulationDiverged
    try:
        scene = _scene(job)
    except InputError as exc:            # parameters the scene refuses: a failed run, not a crash
        return SimulationResult.refused(len(job.times_s), exc)
    driver = SimulationDriver(scene, wrench_frame='world', on_divergence='raise')
    driver.reset()
    start, axis = scene.needle_pose[0], scene.needle.axis.copy()
    wall0 = time.perf_counter()
    k = len(job.times_s)
    try:
        samples = driver.follow(job.times_s, job.positions)
    except SimulationDiverged as exc:
        nan = np.full(k, np.nan)
        return SimulationResult(nan, nan, nan, np.zeros(0), np.zeros(0), diverged=str(exc),
                                wall_s=time.perf_counter() - wall0, **_stepping(scene))
    events = scene.puncture_events
    travel = (job.positions - start) @ axis
    puncture_travel = np.interp([e['time_s'] for e in events], samples.time, travel) if events else np.zeros(0)
    layers = [k for k, region in enumerate(scene.spec['regions']) if region['membrane']['criterion'] != 'none']
    names = scene.region_names
    layer = [layers.index(names.index(e['region'])) if names.index(e['region']) in layers else -1 for e in events]
    return SimulationResult(samples.time, -(samples.force @ axis), samples.tip_depth,
                            np.asarray(puncture_travel, dtype=float),
                            np.array([e['axial_force_n'] for e in events], dtype=float),
                            wall_s=time.perf_counter() - wall0, steps=samples.substeps, **_stepping(scene),
                            puncture_layer=np.array(layer, dtype=np.int64))


def _stepping(scene) -> dict:
    return {'mass_scaling': float(scene.spec['solver']['mass_scaling']), 'time_step_s': float(scene.dt)}


class ResultStore:
    """Results by job key in ``directory`` (npz files), for resuming an interrupted study."""

    def __init__(self, directory):
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)

    def _path(self, key: str) -> Path:
        return self.directory / f'{key}.npz'

    def get(self, key: str) -> SimulationResult | None:
        try:
            with np.load(self._path(key), allow_pickle=False) as data:
                return SimulationResult(data['time_s'], data['axial_force_n'], data['tip_depth_m'],
                                        data['puncture_travel_m'], data['puncture_force_n'],
                                        str(data['diverged']), float(data['wall_s']), int(data['steps']),
                                        float(data['mass_scaling']), float(data['time_step_s']),
                                        data['puncture_layer'] if 'puncture_layer' in data else None)
        except (OSError, KeyError, ValueError):
            return None

    def put(self, key: str, result: SimulationResult) -> None:
        path = self._path(key)
        temporary = path.with_suffix('.tmp.npz')
        np.savez(temporary, time_s=result.time_s, axial_force_n=result.axial_force_n,
                 tip_depth_m=result.tip_depth_m, puncture_travel_m=result.puncture_travel_m,
                 puncture_force_n=result.puncture_force_n, diverged=np.array(result.diverged),
                 wall_s=np.array(result.wall_s), steps=np.array(result.steps),
                 mass_scaling=np.array(result.mass_scaling), time_step_s=np.array(result.time_step_s),
                 puncture_layer=np.asarray(result.puncture_layer, dtype=np.int64))
        temporary.replace(path)         # whole or absent: an interruption leaves no half file
