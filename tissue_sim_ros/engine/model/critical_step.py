"""The explicit solver's critical time step, 2 / omega_max, of a TensorMassModel's linearised forces.

- :func:`lanczos`: omega_max^2, the largest eigenvalue of M^-1/2 K M^-1/2, by scipy's ARPACK
  Lanczos on the force kernel, for the unconstrained body (constraints only lower it, so the
  result is safe for any boundary conditions);
- :func:`element_bound`: the element eigenvalue inequality, max over elements of the largest
  eigenvalue of M_e^-1 K_e (lumped M_e = rho V / 4 per vertex), a guaranteed upper bound on
  omega_max^2, hence a smaller, always-safe step.
"""
import numpy as np

from tissue_sim_ros.engine.compiled import cache as compile_cache

__all__ = ['lanczos', 'element_bound']


def lanczos(model) -> float:
    """2 / omega_max [s] by Lanczos on the model's linear force kernel."""
    compile_cache.wait_for_helper()    # it compiles the linear pass on a first start
    import scipy.sparse.linalg
    mass = model.lumped_masses()
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
    largest = 0.0
    step = 20000
    for start in range(0, model.mesh.n_elements, step):
        stiff = _element_stiffness(model.shape_gradients[start:start + step],
                                   model.volume_lambda[start:start + step],
                                   model.volume_mu[start:start + step])
        eig = np.linalg.eigvalsh(stiff)[:, -1] / (model.element_mass[start:start + step] / 4.0)
        largest = max(largest, float(eig.max()))
    return 2.0 / np.sqrt(largest)


def _element_stiffness(shape_gradients, volume_lambda, volume_mu):
    """Element stiffness matrices (m, 12, 12): K_jk = V (lambda a_j a_k^T + mu a_k a_j^T + mu a_j.a_k I)."""
    a = np.concatenate([-shape_gradients.sum(axis=1, keepdims=True), shape_gradients], axis=1)  # (m,4,3)
    outer = np.einsum('mjr,mks->mjkrs', a, a)                    # a_j[r] a_k[s]
    dots = np.einsum('mjr,mkr->mjk', a, a)
    stiff = (volume_lambda[:, None, None, None, None] * outer
             + volume_mu[:, None, None, None, None] * outer.transpose(0, 2, 1, 4, 3)
             + volume_mu[:, None, None, None, None] * dots[:, :, :, None, None] * np.eye(3))
    return stiff.transpose(0, 1, 3, 2, 4).reshape(-1, 12, 12)
