"""Bonds held exactly inside an implicit step: the needle's bonded contact as linear equality
constraints of Newton's step (issue 17 item 1).

A bonded contact holds sample material points at targets fixed to the needle end: per axis r,
W X_r = T_r, with X the positions (rest + displacement) of the bonded nodes and W (samples x
nodes) their barycentric weights. Applied after an implicit step through each DOF's own
stiffness (the uncoupled correction), a bond moves its nodes with their neighbours held, so it
reported the force that pushes those nodes alone: on the coarse default scene at 5 mm/s the
capsule ruptured at 2.8 mm of tip travel instead of 7.6 mm. Here the step itself holds them:

- the predictor is moved onto the constraint, x += D^-1 W^T Pi (T - W X), Pi = (W D^-1 W^T)^+
  per axis, D the conjugate gradient's (Jacobi) preconditioner;
- the conjugate gradient is the projected one (Gould, Hribar & Nocedal, SIAM J. Sci. Comput. 23,
  2001): the preconditioned residual z = D^-1 r is projected, z -= D^-1 W^T Pi W z, so every
  search direction keeps W X = T and the Newton step with it;
- Newton's residual R is taken without its part in the constraints' range, R - W^T lambda with
  lambda = Pi W D^-1 R: what is left is the unbalance the bonds cannot take;
- at the converged state the bonds' multipliers lambda_s are the force each sample puts on the
  tissue, the exact reaction of the constraint (a prescribed displacement's, for points).

Only the bonds are held this way: the shaft's lateral hold and the friction and cutting laws
still act after the step (their forces are bounded by their laws while the tissue slips).
"""
import numpy as np

__all__ = ['BondSet']


class BondSet:
    """The bonds of one implicit step: (nodes (j,), weights (s, j), targets (s, 3) [m], forces
    (s, 3) written at the end [N]) per bonded contact, factored for the step's preconditioner."""

    def __init__(self):
        self.bonds = []
        self._factors = []
        self._key = None

    def __bool__(self):
        return bool(self.bonds)

    def set(self, bonds, inverse_diagonal, key):
        """The step's bonds; Pi per axis, refactored when the bonds (by identity) or the
        preconditioner (``key``) change."""
        self.bonds = list(bonds)
        key = (key, tuple(id(b[1]) for b in self.bonds))
        if key == self._key:
            return
        self._factors = []
        for nodes, weights, _, _ in self.bonds:
            d = inverse_diagonal[nodes]                                     # (j, 3)
            system = np.einsum('sj,jr,tj->rst', weights, d, weights)
            self._factors.append(np.stack([np.linalg.pinv(system[r], rcond=1e-10, hermitian=True)
                                           for r in range(3)]))
        self._key = key

    def _correct(self, vector, inverse_diagonal, amounts, factor, nodes, weights):
        """vector[nodes] += D^-1 W^T Pi amounts, per axis."""
        lam = np.einsum('rst,tr->sr', factor, amounts)                      # (s, 3)
        vector[nodes] += inverse_diagonal[nodes] * (weights.T @ lam)

    def satisfy(self, rest, displacement, inverse_diagonal):
        """Move ``displacement`` onto the bonds (the smallest move in the D metric)."""
        for (nodes, weights, targets, _), factor in zip(self.bonds, self._factors):
            gap = targets - weights @ (rest[nodes] + displacement[nodes])
            self._correct(displacement, inverse_diagonal, gap, factor, nodes, weights)

    def project(self, z, inverse_diagonal):
        """z -= D^-1 W^T Pi W z: a preconditioned residual made to keep the bonds."""
        for (nodes, weights, _, _), factor in zip(self.bonds, self._factors):
            self._correct(z, inverse_diagonal, -(weights @ z[nodes]), factor, nodes, weights)

    def multipliers(self, residual, inverse_diagonal, k):
        """lambda (s, 3) of bond set ``k`` for an unbalanced force ``residual``."""
        nodes, weights = self.bonds[k][0], self.bonds[k][1]
        return np.einsum('rst,tr->sr', self._factors[k], weights @ (inverse_diagonal[nodes] * residual[nodes]))

    def remove_reactions(self, residual, inverse_diagonal):
        """residual -= W^T lambda: what the bonds cannot take."""
        for k, (nodes, weights, _, _) in enumerate(self.bonds):
            residual[nodes] -= weights.T @ self.multipliers(residual, inverse_diagonal, k)

    def write_forces(self, unbalanced, inverse_diagonal):
        """Each sample's force on the tissue at the converged state: its multiplier."""
        for k, bond in enumerate(self.bonds):
            bond[3][:] = self.multipliers(unbalanced, inverse_diagonal, k)
