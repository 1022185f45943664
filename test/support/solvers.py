"""A static solve with scipy, independent of the explicit solver."""
import numpy as np


def static_solve(model, constrained_dofs, prescribed_values):
    """Solve K u = 0 on the free DOFs with u fixed on ``constrained_dofs`` (scipy, independent of the explicit solver)."""
    import scipy.sparse.linalg
    stiffness = model.stiffness_matrix().tocsr()
    n_dofs = stiffness.shape[0]
    u = np.zeros(n_dofs)
    u[constrained_dofs] = prescribed_values
    free = np.setdiff1d(np.arange(n_dofs), constrained_dofs)
    rhs = -stiffness[free][:, constrained_dofs] @ u[constrained_dofs]
    u[free] = scipy.sparse.linalg.spsolve(stiffness[free][:, free].tocsc(), rhs)
    return u.reshape(-1, 3)
