"""A flexible needle's path through the tissue: where its tip went, how it curved.

:func:`insert_path` drives a scene's needle straight along its initial axis (the base does not
steer) and records where the tip is each tick; ``roll_at_m`` turns the base by 180 degrees about
its axis on the way (the input pose's roll turns the bevel), as a duty-cycled or flip planner would.
:func:`path_curvature` measures the path a bevel tip cut: its deflection from the base's axis in
its bending plane, the radius of the circle through it and how much the radius varies along it
(Webster et al. 2006: a bevel tip in a homogeneous block follows a constant-curvature arc).
Its radius is that of the circle tangent to the axis at the entry through the path
(:func:`arc_radius`).
``tissue-sim bench steering`` (:mod:`tissue_sim_ros.bench.steering`) prints these figures.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ['TipPath', 'insert_path', 'rolled', 'PathCurvature', 'path_curvature', 'arc_radius']


@dataclass
class TipPath:
    """A tick-by-tick record of an insertion: the base's travel along its initial axis [m], the
    tip's apex (k, 3) [m] (world), its distance from the base's axis [m], the phase, the axis and
    the base's start, and the scene's wall time [s]."""
    travel: np.ndarray
    tip: np.ndarray
    deflection: np.ndarray
    phase: list
    axis: np.ndarray
    start: np.ndarray
    force: np.ndarray
    wall_s: float = 0.0

    def inside(self) -> np.ndarray:
        """Where the needle is in the tissue (a boolean per tick)."""
        return np.array([p in ('inserted', 'retracting') for p in self.phase])


def rolled(orientation, angle_rad: float) -> np.ndarray:
    """The orientation (x, y, z, w) turned by ``angle_rad`` about its own +z (the needle's roll)."""
    x, y, z, w = orientation
    c, s = np.cos(0.5 * angle_rad), np.sin(0.5 * angle_rad)
    return np.array([x * c + y * s, y * c - x * s, z * c + w * s, w * c - z * s])


def insert_path(scene, travel_m: float, speed_m_s: float, *, tick_s: float = 0.02, roll_at_m: float | None = None,
                roll_over_m: float = 0.001) -> TipPath:
    """Insert the scene's needle by ``travel_m`` from its start along its axis at ``speed_m_s``,
    sampled every ``tick_s``; with ``roll_at_m``, the base turns by 180 degrees about its axis
    while it travels ``roll_over_m`` from there (evenly, slerped between ticks). Returns the
    :class:`TipPath`."""
    import time

    from tissue_sim_ros.engine.driver import SimulationDriver
    driver = SimulationDriver(scene, wrench_frame='world', on_divergence='raise')
    start, orientation = scene.needle_pose
    axis = scene.needle.axis.copy()
    n = max(1, int(np.ceil(travel_m / speed_m_s / tick_s - 1e-9)))
    travel = travel_m * np.arange(1, n + 1) / n
    roll = np.zeros(n)
    if roll_at_m is not None:
        if roll_over_m < 2.0 * speed_m_s * tick_s:
            raise ValueError(f'roll_over_m = {roll_over_m!r}: the roll would turn the base by more than 90 degrees '
                             f'a tick (the pose between ticks is slerped the short way); expected at least '
                             f'{2.0 * speed_m_s * tick_s:.3g} m at {speed_m_s:g} m/s')
        roll = np.pi * np.clip((travel - roll_at_m) / roll_over_m, 0.0, 1.0)
    tip, deflection, force, phase = np.empty((n, 3)), np.empty(n), np.empty((n, 3)), []
    wall0 = time.perf_counter()
    for k in range(n):
        driver.advance(tick_s, start + travel[k] * axis, rolled(orientation, roll[k]))
        tip[k], deflection[k], force[k] = scene.needle.tip, scene.tip_deflection, driver.force
        phase.append(str(scene.phase))
    return TipPath(travel, tip, deflection, phase, axis, start, force, time.perf_counter() - wall0)


def arc_radius(along: np.ndarray, lateral: np.ndarray) -> float:
    """The radius [m] of the circle tangent to the base's axis at the entry (along = lateral = 0)
    that passes closest to the points (along, lateral) [m]: the least-squares R of
    2 R lateral = along^2 + lateral^2, exact for points on such a circle; signed (negative for
    a bend toward -lateral); inf for points on the axis. The arc of Webster et al. (2006): a bevel
    tip in a homogeneous block leaves the entry along the axis and follows a circle. Measured
    from the entry, the radius takes the path's whole lateral offset, not its second derivative
    over a stretch: the mesh's noise, a few microns a cell, moves a local curvature of a path that
    turns by a few degrees by tens of percent, this radius by a few."""
    along, lateral = np.asarray(along, dtype=float), np.asarray(lateral, dtype=float)
    den = 2.0 * float(np.sum(lateral * lateral))
    num = float(np.sum(lateral * (along * along + lateral * lateral)))
    if len(along) == 0 or den == 0.0 or num == 0.0:
        return float('inf')
    return num / den


@dataclass
class PathCurvature:
    """A path's bend: ``direction`` (3,) the unit lateral direction it bent toward (world),
    ``along`` and ``lateral`` (k,) [m] the tip's depth from the entry along the base axis and its
    deflection toward ``direction``, the radius [m] of the arc from the entry through the last
    ``fraction`` of the path (:func:`arc_radius`), the radii through each of ``windows`` equal
    parts of that stretch and their spread (max - min) / mean: a constant curvature has one radius
    for every part; ``toward``: whether it bends toward ``direction``."""
    direction: np.ndarray
    along: np.ndarray
    lateral: np.ndarray
    radius_m: float
    window_radii_m: np.ndarray
    spread: float
    toward: bool = True


def path_curvature(path: TipPath, *, fraction: float = 0.6, windows: int = 3, direction=None) -> PathCurvature:
    """The bend of the tip's path inside the tissue (:class:`PathCurvature`): its deflection
    from the base's axis, in the plane of the axis and the last deflection (or ``direction``:
    take it before a roll turns the needle), and its curvature over its last ``fraction`` (by
    depth), whole and in ``windows`` parts."""
    inside = path.inside()
    tip = path.tip[inside]
    offset = tip - path.start
    along = offset @ path.axis
    lateral_vectors = offset - along[:, None] * path.axis
    if direction is None:
        deepest = lateral_vectors[-1]
        direction = deepest / np.linalg.norm(deepest) if np.linalg.norm(deepest) > 0 else np.zeros(3)
    direction = np.asarray(direction, dtype=float)
    along = along - along[0]
    lateral = lateral_vectors @ direction
    last = along >= (1.0 - fraction) * along[-1]
    signed = arc_radius(along[last], lateral[last])
    parts = np.array_split(np.flatnonzero(last), windows)
    radii = np.abs([arc_radius(along[p], lateral[p]) for p in parts])
    finite = radii[np.isfinite(radii)]
    spread = float((finite.max() - finite.min()) / finite.mean()) if len(finite) == windows else float('inf')
    return PathCurvature(direction, along, lateral, abs(signed), radii, spread, bool(signed > 0.0))
