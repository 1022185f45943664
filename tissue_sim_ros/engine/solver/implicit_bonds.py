"""Bonds held exactly inside an implicit step: the needle's bonded contact as linear equality
constraints of Newton's step.

A bond row holds a material point (weights w_k over nodes k) along a direction d at a target:
sum_k w_k d . X_k = t, with X the positions (rest + displacement). A bonded contact holds each
sample along the three axes, a row per axis. Together the rows of every needle are C X = t, C
sparse (rows x 3n), factored as one, so bonds that share nodes are held together. Applied after
an implicit step through each DOF's own stiffness (the uncoupled correction), a bond would move
its nodes with their neighbours held and report the force that pushes those nodes alone, far
above the body's (the capsule would rupture early). Here the step itself holds them:

- the predictor is moved onto the rows, x += D^-1 C^T Pi (t - C X), Pi = (C D^-1 C^T)^+, D the
  conjugate gradient's (Jacobi) preconditioner;
- the conjugate gradient is the projected one (Gould, Hribar & Nocedal, SIAM J. Sci. Comput. 23,
  2001): the preconditioned residual z = D^-1 r is projected, z -= D^-1 C^T Pi C z, so every
  search direction keeps C X = t and the Newton step with it; r is kept free of the rows' part,
  which it otherwise gathers by rounding (their section 6);
- Newton's residual R is taken without its part in the rows' range, R - C^T lambda with
  lambda = Pi C D^-1 R: what is left is the unbalance the bonds cannot take;
- at the converged state the multipliers lambda are the bonds' forces on the tissue along their
  directions, the exact reaction of the constraint (a prescribed displacement's, for nodes).
"""
import numpy as np
from scipy import sparse

__all__ = ['BondRows', 'BondSet']

#: rows whose combination is this small against the largest are taken as dependent (least
#: squares): a patch's samples in one triangle ask its three nodes for the same thing
RCOND = 1e-10


class BondRows:
    """Rows of bonds: nodes (m, J) and weights (m, J) of each row's material point (padding:
    weight 0), directions (m, 3) unit, targets (m,) [m] along them; ``forces`` (m,) [N] is
    written at the end of the step (each row's force on the tissue along its direction). Its
    points and directions are fixed once made (BondSet keeps their factor while the same rows
    come back); the targets may change every step."""

    def __init__(self, nodes, weights, directions, targets):
        self.nodes = np.ascontiguousarray(nodes, dtype=np.int64)
        self.weights = np.ascontiguousarray(weights, dtype=float)
        self.directions = np.ascontiguousarray(directions, dtype=float)
        self.targets = np.ascontiguousarray(targets, dtype=float)
        self.forces = np.zeros(len(self.targets))

    @classmethod
    def along_axes(cls, nodes, weights, targets):
        """Samples (s, J) held at target points (s, 3) along x, y and z: rows 3s + r."""
        s = len(targets)
        return cls(np.repeat(nodes, 3, axis=0), np.repeat(weights, 3, axis=0), np.tile(np.eye(3), (s, 1)),
                   np.asarray(targets, dtype=float).reshape(-1))


class BondSet:
    """The bond rows of one implicit step (BondRows, from every coupling), stacked into C and
    factored for the step's preconditioner."""

    def __init__(self):
        self.rows = []
        self._c = None
        self._key = None

    def __bool__(self):
        return bool(self.rows)

    def set(self, rows, inverse_diagonal, key, n_nodes):
        """The step's rows; C and Pi rebuilt when the rows (by identity) or the preconditioner
        (``key``) change."""
        self.rows = [r for r in rows if len(r.targets)]
        if not self.rows:
            return
        self._targets = np.concatenate([r.targets for r in self.rows])
        if (self._key is not None and self._key[0] == (key, n_nodes) and len(self._key[1]) == len(self.rows)
                and all(a is b for a, b in zip(self._key[1], self.rows))):
            return
        key = ((key, n_nodes), tuple(self.rows))      # the rows themselves: by identity
        entries_row, entries_col, entries_val = [], [], []
        start = 0
        for r in self.rows:
            m, j = r.nodes.shape
            row = np.repeat(np.arange(start, start + m), j * 3)
            col = (3 * r.nodes[:, :, None] + np.arange(3)).ravel()
            val = (r.weights[:, :, None] * r.directions[:, None, :]).ravel()
            entries_row.append(row)
            entries_col.append(col)
            entries_val.append(val)
            start += m
        c = sparse.csr_matrix((np.concatenate(entries_val), (np.concatenate(entries_row),
                                                            np.concatenate(entries_col))),
                              shape=(start, 3 * n_nodes))
        c.sum_duplicates()
        system = (c.multiply(inverse_diagonal.reshape(1, -1)) @ c.T).toarray()
        self._c, self._ct = c, c.T.tocsr()
        self._pi = np.linalg.pinv(system, rcond=RCOND, hermitian=True)
        self._key = key

    def _correct(self, vector, inverse_diagonal, amounts):
        """vector += D^-1 C^T Pi amounts."""
        vector += inverse_diagonal * (self._ct @ (self._pi @ amounts)).reshape(-1, 3)

    def satisfy(self, rest, displacement, inverse_diagonal):
        """Move ``displacement`` onto the rows (the smallest move in the D metric)."""
        self._correct(displacement, inverse_diagonal,
                      self._targets - self._c @ (rest + displacement).reshape(-1))

    def project(self, z, inverse_diagonal):
        """z -= D^-1 C^T Pi C z: a preconditioned residual made to keep the rows."""
        self._correct(z, inverse_diagonal, -(self._c @ z.reshape(-1)))

    def multipliers(self, residual, inverse_diagonal):
        """lambda (m,) for an unbalanced force ``residual``: Pi C D^-1 R."""
        return self._pi @ (self._c @ (inverse_diagonal * residual).reshape(-1))

    def remove_reactions(self, residual, inverse_diagonal):
        """residual -= C^T lambda: what the bonds cannot take."""
        residual -= (self._ct @ self.multipliers(residual, inverse_diagonal)).reshape(-1, 3)

    def write_forces(self, unbalanced, inverse_diagonal):
        """Each row's force on the tissue at the converged state: its multiplier."""
        lam = self.multipliers(unbalanced, inverse_diagonal)
        start = 0
        for r in self.rows:
            r.forces[:] = lam[start:start + len(r.targets)]
            start += len(r.targets)
