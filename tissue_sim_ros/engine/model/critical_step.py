"""The explicit solver's critical time step, 2 / omega_max, of a TensorMassModel's linearised forces.

- :func:`lanczos`: omega_max^2, the largest eigenvalue of M^-1/2 K M^-1/2, by scipy's ARPACK
  Lanczos on the force kernel, for the unconstrained body (constraints only lower it, so the
  result is safe for any boundary conditions);
- :func:`element_bound`: the element eigenvalue inequality, max over elements of the largest
  eigenvalue of M_e^-1 K_e (lumped M_e = rho V / 4 per vertex), a guaranteed upper bound on
  omega_max^2, hence a smaller, always-safe step;
- :func:`element_steps`: each element's own step 2 / sqrt(that eigenvalue), and
  :func:`selective_mass_factors`: the factors on node masses that bring every element's own step
  up to a target (selective mass scaling).

Why selective mass scaling works on organ meshes: a mesher's few smallest or flattest elements set
the whole mesh's step. On the organ example at 53742 elements their own steps run from 0.29 ms
(the least) over 0.59 ms (1 %) to 3.8 ms (the median), with mass scaling 400; adding mass only at
the nodes of the elements below a target lifts the step of the whole mesh while the total mass
hardly moves. The element inequality makes it safe: with every node of element e at least
f_e = (target / step_e)^2 times its mass, M_e^-1 K_e's largest eigenvalue falls by f_e, and
omega_max^2 <= max_e of them, so the whole mesh's step is at least the target.
"""
import math

import numpy as np

from tissue_sim_ros.engine.compiled import cache as compile_cache

__all__ = ['lanczos', 'element_bound', 'element_steps', 'selective_mass_factors']


def lanczos(model, mass_factor=None) -> float:
    """2 / omega_max [s] by Lanczos on the model's linear force kernel; ``mass_factor`` (n,): a
    factor on each node's lumped mass (None: 1)."""
    compile_cache.wait_for_helper()    # it compiles the linear pass on a first start
    import scipy.sparse.linalg
    mass = model.lumped_masses() if mass_factor is None else model.lumped_masses() * mass_factor
    inv_sqrt_mass = np.repeat(np.where(mass > 0, 1.0 / np.sqrt(np.where(mass > 0, mass, 1.0)), 0.0), 3)
    u = np.empty((model.mesh.n_nodes, 3))
    f = np.empty((model.mesh.n_nodes, 3))

    def apply(x):
        u.ravel()[:] = inv_sqrt_mass * x.ravel()
        model.linear_forces(u, out=f)
        return -inv_sqrt_mass * f.ravel()

    n_dofs = 3 * model.mesh.n_nodes
    operator = scipy.sparse.linalg.LinearOperator((n_dofs, n_dofs), matvec=apply, dtype=float)
    start = np.random.default_rng(0).normal(size=n_dofs)
    largest = scipy.sparse.linalg.eigsh(operator, k=1, which='LA', v0=start, tol=1e-6,
                                        return_eigenvectors=False)[0]
    return 2.0 / np.sqrt(largest * (1.0 + 1e-6))


def element_bound(model) -> float:
    """2 / sqrt(max over elements of the largest eigenvalue of M_e^-1 K_e) [s]."""
    return float(element_steps(model).min())


def element_steps(model) -> np.ndarray:
    """(m,) each element's own critical step 2 / sqrt(largest eigenvalue of M_e^-1 K_e) [s]."""
    steps = np.empty(model.mesh.n_elements)
    chunk = 20000
    for start in range(0, model.mesh.n_elements, chunk):
        part = slice(start, start + chunk)
        stiff = _element_stiffness(model.shape_gradients[part], model.volume_lambda[part], model.volume_mu[part])
        largest = np.linalg.eigvalsh(stiff)[:, -1] / (model.element_mass[part] / 4.0)
        steps[part] = 2.0 / np.sqrt(largest)
    return steps


def selective_mass_factors(model, factor, mass_factor=None, tolerance=0.02) -> np.ndarray:
    """(n,) factors on the nodes' lumped masses (on top of ``mass_factor``, the ones they have;
    None: 1) that raise the critical step (Lanczos) at least ``factor``-fold with little mass: the
    nodes of every element whose own step is below a target T take the mass that brings it to T
    (a node the largest (T / step_e)^2 of its elements); T is the least, within ``tolerance``, that
    lifts the step enough, found by bisection between the shortest element's step (nothing added)
    and ``factor`` times the step now (enough by the element inequality: module docstring). A
    uniform mass scaling cancels out of the ratios."""
    n_nodes = model.mesh.n_nodes
    current = np.ones(n_nodes) if mass_factor is None else np.asarray(mass_factor, dtype=float)
    goal = float(factor) * lanczos(model, mass_factor)
    tetrahedra = model.mesh.tetrahedra
    steps = element_steps(model) * np.sqrt(current[tetrahedra].min(axis=1))   # a lower bound with them

    def raised(target):
        needed = np.maximum((target / steps) ** 2, 1.0)
        out = np.ones(n_nodes)
        np.maximum.at(out, tetrahedra.ravel(), np.repeat(needed, 4))
        return current * out

    low, high = float(steps.min()), goal
    best = raised(high)
    while low < high and high / low > 1.0 + tolerance:
        middle = math.sqrt(low * high)
        trial = raised(middle)
        if lanczos(model, trial) >= goal:
            high, best = middle, trial
        else:
            low = middle
    return best


def _element_stiffness(shape_gradients, volume_lambda, volume_mu):
    """Element stiffness matrices (m, 12, 12): K_jk = V (lambda a_j a_k^T + mu a_k a_j^T + mu a_j.a_k I)."""
    a = np.concatenate([-shape_gradients.sum(axis=1, keepdims=True), shape_gradients], axis=1)  # (m,4,3)
    outer = np.einsum('mjr,mks->mjkrs', a, a)                    # a_j[r] a_k[s]
    dots = np.einsum('mjr,mkr->mjk', a, a)
    stiff = (volume_lambda[:, None, None, None, None] * outer
             + volume_mu[:, None, None, None, None] * outer.transpose(0, 2, 1, 4, 3)
             + volume_mu[:, None, None, None, None] * dots[:, :, :, None, None] * np.eye(3))
    return stiff.transpose(0, 1, 3, 2, 4).reshape(-1, 12, 12)
