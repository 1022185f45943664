"""The error of each degradation-ladder level, measured on the scene itself, once, cached.

The probe is a standard indentation: the scene's needle is brought along its axis to just above
the tissue surface under its tip (quickly: nothing touches yet), then driven at
``PROBE_SPEED_M_S`` to ``PROBE_PAST_CONTACT_M`` past the surface, the loading a puncture needs.
It is run at level 0 and at every lower level of the scene's
:class:`~tissue_sim_ros.engine.ladder.DegradationLadder`; a level's error is the RMS
of its axial force minus level 0's over the slow part, divided by level 0's force range there
(NRMSE), the measure the comparison with load-cell data uses. A level that diverges scores inf.

The errors depend only on the scene, so they are kept in the user cache
(``ladder/<hash>.json``, the hash of the scene's keys, its mesh file, the package version, what
the rungs change and the probe's constants): a node measures a scene once (about 1.5 s of CPU on the default scene,
in a background thread), later starts read the file.
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

__all__ = ['PROBE_SPEED_M_S', 'PROBE_PAST_CONTACT_M', 'probe_errors', 'cached_probe_errors',
           'scene_hash']

PROBE_SPEED_M_S = 0.005
PROBE_PAST_CONTACT_M = 0.004
_APPROACH_SPEED_M_S = 0.05
_CLEARANCE_M = 0.0005
_TICK_S = 0.02


def _surface_gap(scene) -> float:
    """Distance [m] from the needle tip, along its axis, to the tissue surface (inf: none)."""
    from tissue_sim_ros.engine.needle.kernels import first_surface_hit
    needle = scene.needle
    hit, t, _, _, _ = first_surface_hit(scene.rest_positions, scene.displacement,
                                        needle.surface_triangles, needle.tip.copy(),
                                        needle.axis.copy(), 0.0, 10.0)
    return float(t) if hit >= 0 else float('inf')


def _schedule(gap: float):
    """(times, travels, slow mask) of the probe: fast to the clearance, slow past the surface."""
    fast = max(gap - _CLEARANCE_M, 0.0)
    n_fast = int(np.ceil(fast / (_APPROACH_SPEED_M_S * _TICK_S)))
    slow = gap - fast + PROBE_PAST_CONTACT_M
    n_slow = int(np.ceil(slow / (PROBE_SPEED_M_S * _TICK_S)))
    travel = np.concatenate([np.linspace(0.0, fast, n_fast + 1)[1:],
                             fast + np.linspace(0.0, slow, n_slow + 1)[1:]])
    times = np.concatenate([np.arange(1, n_fast + 1) * fast / max(n_fast, 1) / _APPROACH_SPEED_M_S,
                            fast / _APPROACH_SPEED_M_S + np.arange(1, n_slow + 1) * _TICK_S
                            * slow / (n_slow * PROBE_SPEED_M_S * _TICK_S)])
    return times, travel, np.arange(len(travel)) >= n_fast


def probe_errors(scene, ladder) -> list[float]:
    """Each level's NRMSE against level 0 over the probe (see the module docstring). Runs on
    ``scene`` (a scene of its own: it is reset and left at level 0 and rest)."""
    from tissue_sim_ros.engine.driver import SimulationDriver
    from tissue_sim_ros.errors import SimulationDiverged
    driver = SimulationDriver(scene, on_divergence='raise')
    gap = _surface_gap(scene)
    if not np.isfinite(gap):
        raise ValueError('the ladder probe found no tissue surface along the needle axis')
    times, travel, slow = _schedule(gap)
    start, orientation = scene.needle_pose
    axis = scene.needle.axis.copy()
    positions = start + travel[:, None] * axis
    forces = []
    for level in range(len(ladder.rungs)):
        ladder.set_level(level)
        driver.reset()
        try:
            samples = driver.follow(times, positions, np.repeat(orientation[None], len(times), 0))
            forces.append(-(samples.force[slow] @ axis))
        except SimulationDiverged:
            forces.append(None)
    ladder.set_level(0)
    driver.reset()
    reference = forces[0]
    scale = float(np.ptp(reference)) or 1.0
    return [float('inf') if f is None else float(np.sqrt(np.mean((f - reference) ** 2)) / scale)
            for f in forces]


def scene_hash(scene) -> str:
    """A hash of what the probe's result depends on: the scene's keys, its mesh file's bytes,
    the package version, what the rungs change and the probe's constants."""
    from tissue_sim_ros import __version__
    from tissue_sim_ros.engine.ladder import RUNG_RULES
    digest = hashlib.sha256()
    digest.update(json.dumps(scene.spec, sort_keys=True, default=str).encode())
    if scene.spec['mesh']['generator'] == 'file':
        path = Path(scene.spec['mesh']['file'])
        path = path if path.is_absolute() else Path(scene.base_dir) / path
        digest.update(path.read_bytes())
    digest.update(repr((__version__, RUNG_RULES, PROBE_SPEED_M_S, PROBE_PAST_CONTACT_M, _APPROACH_SPEED_M_S,
                        _CLEARANCE_M, _TICK_S)).encode())
    return digest.hexdigest()[:24]


def cached_probe_errors(scene, make_ladder, cache_dir=None) -> list[float]:
    """The probe's errors for ``scene``'s ladder, from the cache or measured on a copy of the
    scene (``make_ladder(scene) -> DegradationLadder``) and written there."""
    from tissue_sim_ros.system.user_cache import user_cache_dir
    directory = Path(cache_dir or user_cache_dir('ladder') or '.')
    path = directory / f'{scene_hash(scene)}.json'
    try:
        return [float(e) for e in json.loads(path.read_text())['errors']]
    except (OSError, ValueError, KeyError, TypeError):
        pass
    copy = scene.copy()
    copy.model.set_threads(1)
    errors = probe_errors(copy, make_ladder(copy))
    try:
        directory.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({'errors': errors}))
    except OSError:
        pass                       # a read-only home: measured again next time
    return errors
