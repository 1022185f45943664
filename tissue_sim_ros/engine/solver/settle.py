"""The tissue settled under its constant loads (gravity) on its supports, before a needle moves.

The static equilibrium f(u) - K_s u + f_g = 0 on the free DOFs (f the element pass's elastic
force, K_s the foundations', f_g the body forces) is solved by modified Newton: each iteration
u += K0^-1 r(u), with K0 the rest state's linear stiffness plus the foundations', factored once
(scipy's sparse LU). For the linear model that is the exact solve in one iteration; for the
non-linear ones it converges linearly at the small strains an organ's own weight makes, to the
non-linear model's own equilibrium, with its non-linearity threshold. Where the threshold keeps the
iteration from converging (a settled organ is turned a little on its supports, its elements'
displacement gradients spread around a threshold such as 0.05, and the force jumps where an
element crosses it: the residual stops falling), it is set aside and the state is the full
model's equilibrium (every element on the non-linear path); the run then starts a little out of
balance, by the threshold's own approximation. The state it finds is the one a reset returns to
(``Simulation.set_initial_state``); :func:`settled_state` caches it per scene, keyed by the
arrays and values that decide it.
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np

from tissue_sim_ros.errors import SceneError

__all__ = ['FLOAT32_TOLERANCE', 'STALL_ITERATIONS', 'settle', 'settled_state']

#: the residual a float32 element pass settles to (relative to the loads): its forces carry its
#: round-off, about 1e-7 of the elements' stresses, which at equilibrium cancel to a load thousands
#: of times smaller (the organ example at 54000 tetrahedra stalled at 1.3e-4)
FLOAT32_TOLERANCE = 1e-3
#: the iteration with the threshold gives up when its residual has not halved over this many
STALL_ITERATIONS = 20
#: how the state is found, in the cache key: a change here settles every scene again
_RULES = 'modified Newton; the threshold set aside where it stalls; float32 to 1e-3'


def _stiffness(simulation, free):
    import scipy.sparse
    model = simulation.model
    n = model.mesh.n_nodes
    k = model.stiffness_matrix().tocsr()
    supported = np.flatnonzero(simulation.support_rows >= 0)
    if len(supported):
        from tissue_sim_ros.engine.solver.supports import SIX
        rows, cols, values = [], [], []
        six = simulation.support_stiffness[simulation.support_rows[supported]]
        for c, (a, b) in enumerate(SIX):
            rows += [3 * supported + a] + ([3 * supported + b] if a != b else [])
            cols += [3 * supported + b] + ([3 * supported + a] if a != b else [])
            values += [six[:, c]] + ([six[:, c]] if a != b else [])
        k = k + scipy.sparse.csr_matrix((np.concatenate(values), (np.concatenate(rows), np.concatenate(cols))),
                                        shape=(3 * n, 3 * n))
    index = np.flatnonzero(free.ravel())
    return k[index][:, index].tocsc(), index


def settle(simulation, tolerance=1e-9, max_iterations=200) -> tuple[np.ndarray, dict]:
    """(displacement (n, 3), {'iterations', 'residual'}) of the equilibrium under the
    simulation's ``body_forces`` (module docstring); the residual is relative to the loads, at
    most ``tolerance`` (``FLOAT32_TOLERANCE`` for a float32 model). Raises SceneError when it does
    not converge (supports too soft for the load)."""
    from scipy.sparse.linalg import splu
    model = simulation.model
    if getattr(model, 'precision', 'float64') == 'float32':
        tolerance = max(tolerance, FLOAT32_TOLERANCE)
    free = simulation.dof_kind == 0
    loads = simulation.body_forces
    scale = float(np.linalg.norm(loads * free))
    u = np.zeros_like(loads)
    if scale == 0.0:
        return u, {'iterations': 0, 'residual': 0.0}
    matrix, index = _stiffness(simulation, free)
    try:
        factor = splu(matrix)
    except RuntimeError as exc:         # singular: a free part of the body has no support
        raise SceneError(f'solver.gravity_m_s2: the tissue cannot be settled under gravity ({exc}): some part '
                         'of it is held by no support (boundary.fixed, boundary.springs)') from exc
    force = np.empty_like(u)
    residual = np.inf
    threshold = model.nonlinearity_threshold
    try:
        for aside in (False, True) if threshold > 0.0 else (False,):
            model.set_nonlinearity_threshold(0.0 if aside else threshold)
            u[:] = 0.0
            history = []
            for iteration in range(1, max_iterations + 1):
                model.internal_forces(u, out=force)
                simulation.add_support_forces(u, force)
                force += loads
                residual = float(np.linalg.norm(force * free)) / scale
                if residual <= tolerance:
                    return u, {'iterations': iteration - 1, 'residual': residual, 'threshold_set_aside': aside}
                history.append(residual)
                if not aside and threshold > 0.0 and len(history) > STALL_ITERATIONS \
                        and residual > 0.5 * history[-1 - STALL_ITERATIONS]:
                    break                  # chattering on the threshold: the full model's equilibrium
                step = factor.solve(force.ravel()[index])
                if not np.isfinite(step).all():
                    break
                u.ravel()[index] += step
    finally:
        model.set_nonlinearity_threshold(threshold)
    raise SceneError(f'solver.gravity_m_s2: the tissue did not settle under gravity ({max_iterations} iterations, '
                     f'residual {residual:.3g} of the load): the supports are too soft for its weight '
                     '(boundary.springs) or the model too non-linear at that sag')


def settled_state(simulation, key_text: str) -> tuple[np.ndarray, dict]:
    """:func:`settle`'s result, read from the per-user cache when this scene (``key_text``: the
    values that decide it) was settled before, else solved and stored."""
    from tissue_sim_ros.system.user_cache import user_cache_dir
    digest = hashlib.sha256((key_text + _RULES).encode())
    model = simulation.model
    for array in (model.mesh.rest_positions, model.tetrahedra, simulation.body_forces, simulation.dof_kind,
                  simulation.support_rows, simulation.support_stiffness):
        digest.update(np.ascontiguousarray(array).tobytes())
    folder = user_cache_dir('settled')
    path = Path(folder) / f'{digest.hexdigest()[:24]}.npy' if folder else None
    if path is not None and path.is_file():
        try:
            u = np.load(path)
            if u.shape == simulation.displacement.shape and np.isfinite(u).all():
                return u, {'iterations': 0, 'residual': None, 'cached': str(path)}
        except (OSError, ValueError):      # an unreadable entry: settled again below
            pass
    u, info = settle(simulation)
    if path is not None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            partial = path.with_suffix('.partial.npy')
            np.save(partial, u)
            os.replace(partial, path)
        except OSError:                    # a cache that cannot be written: the run goes on
            pass
    return u, info
