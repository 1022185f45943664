"""Backward Euler and quasi-static steps of the tensor-mass model: Newton with a matrix-free,
Jacobi-preconditioned conjugate-gradient solve.

The explicit solver's step is bounded by dt_crit = 2 / omega_max; these are not. With x the
displacement at the end of the step and v = (x - u_n) / dt, a step solves for the free DOFs

    backward Euler:  m (v - v_n) / dt + gamma v - f(x, v) - f_ext = 0
    quasi-static:                                 - f(x, v) - f_ext = 0

(f the element pass's internal force, elastic + Kelvin-Voigt; gamma_i = m_i damping_rate_i;
fixed DOFs stay, prescribed ones take their target). Newton's matrix is

    J w = (m / dt^2 + gamma / dt) w - Df[w],   Df[w] = d/de f(x + e w, v + e w / dt)  at e = 0,

the tangent stiffness plus viscous matrix over dt, plus the inertia: symmetric positive definite
for a stable material held against rigid motion. Df[w] is a directional difference of the same
element pass (one force evaluation a product, exact to rounding for the linear model), so every
model and option the explicit solver runs is solved here without assembling a matrix (the
Jacobian-free Newton-Krylov method; Knoll & Keyes, J. Comput. Phys. 193, 2004). The conjugate
gradient's preconditioner is the diagonal of J with the rest-state stiffness (the inertia and
the linear element stiffness's diagonal, sum over elements of V (lambda a_jr^2 + mu (a_jr^2 +
|a_j|^2))). The inner solve stops at a forcing term eta = min(0.01, |R| / |R_0|) times the
residual (Eisenstat & Walker 1996), and a backtracking line search on |R| keeps a step from
overshooting where the law stiffens.

A needle's bonded contact (a flat end or a sharp tip against a membrane) is held inside the
step, as linear equality constraints of Newton's step (engine/solver/implicit_bonds.py: a
projected conjugate gradient), and its force is the constraint's exact reaction, so these steps
load the capsule as the explicit solver does; applied after the step, as the rest of the needle
still is, the bonds would rupture it early.

The needle's other constraints (the shaft's lateral hold and friction, the cutting samples, a
sharp tip's faces) act after the step as with the explicit solver, through each DOF's
compliance in this step (``constraint_inverse_mass``): 1 / (m + dt gamma + dt^2 k_jj + dt c_jj),
the uncoupled constraint correction SOFA uses with its implicit solvers. That compliance is the
node's own with its neighbours held, stiffer than the body's, so after a puncture these steps
read the axial force high and a lateral force the explicit solver does not have: the lateral
force is the bevel's faces pushing the tissue after the step, and the axial excess is friction
over a longer length, the tissue having sprung back at the rupture at once, without inertia.
Both need the contact itself in the solve (the faces as one-sided constraints, friction as a law
of the slip velocity); until then the explicit solver is the one for needle forces after a
puncture. Figures: docs/performance.md.

Two safeguards keep a long run going. The conjugate gradient stops when its residual stagnates
(STAGNATION): its products are differences of the element pass, whose rounding sets a floor,
and under a stiff bond the residual can fall, then grow, with every Newton iteration running to
the iteration cap. And a step that reaches the Newton iteration limit with its residual under
STALL_TOLERANCE of the forces is kept, as a stall (the same floor).

Where Newton's matrix is not positive definite (surface elements crushed around a retracting
needle), its direction can lead nowhere: no fraction of it reduces the residual. Such a step
goes on by pseudo-transient continuation (``_continue``): J + D / delta with the rest
stiffness's diagonal D, delta growing as the residual falls, so it follows the residual's
gradient flow through the indefinite region and ends as Newton on the same root.

The non-linearity threshold makes the residual jump where an element's |H| crosses it, and an
equilibrium can fall in the jump: then there is no root. A residual under the jump that the
elements at the threshold (|H| within THRESHOLD_BAND of t) can make by switching,
2 t^2 (lambda + 2 mu) V^(2/3) the largest of them, is kept as a stall (an upper estimate of the
jump, which the test measures); with no element there the floor is 0. A step with less left
that finds no descent is kept without trying continuation.
"""
import math

import numpy as np

from tissue_sim_ros.engine.model import kernels as forces
from tissue_sim_ros.engine.solver.implicit_bonds import BondSet

__all__ = ['ImplicitStep', 'INTEGRATORS', 'stiffness_diagonal']

INTEGRATORS = ('explicit', 'implicit', 'quasi_static')
#: a step whose Newton iteration stops descending is kept when its residual is below this
#: fraction of the forces acting (a switch between two laws can leave no exact root)
STALL_TOLERANCE = 1e-3
#: the conjugate gradient stops when its residual has not reached a new low (1 % below the
#: lowest) for this many iterations
STAGNATION = 50
#: pseudo-transient continuation (see ImplicitStep._continue): the first pseudo time step, in
#: units of the rest stiffness's diagonal (1: the shift equals it), the most iterations it may
#: add to a step, and the residual growth that makes it shorten its pseudo step instead
CONTINUATION_START = 1.0
CONTINUATION_ITERATIONS = 200
CONTINUATION_GROWTH = 2.0
#: an element is at the non-linearity threshold t when its |H| is within this fraction of t
THRESHOLD_BAND = 1e-3


def stiffness_diagonal(tetrahedra, shape_gradients, volume_lambda, volume_mu, n_nodes):
    """(n, 3) diagonal of the assembled linear stiffness, K_jj[r, r] = V (lambda a_jr^2 +
    mu (a_jr^2 + |a_j|^2)) summed over each node's elements (a_0 = -(a_1 + a_2 + a_3))."""
    a = np.concatenate([-shape_gradients.sum(axis=1, keepdims=True), shape_gradients], axis=1)  # (m, 4, 3)
    squares = a * a
    lengths = squares.sum(axis=2, keepdims=True)
    per_corner = (volume_lambda[:, None, None] * squares
                  + volume_mu[:, None, None] * (squares + lengths))                            # (m, 4, 3)
    out = np.zeros((n_nodes, 3))
    for r in range(3):
        out[:, r] = np.bincount(tetrahedra.ravel(), weights=per_corner[:, :, r].ravel(), minlength=n_nodes)
    return out


class ImplicitStep:
    """One backward Euler or quasi-static step of a Simulation (module docstring); the
    simulation calls :meth:`step` in place of its explicit update."""

    def __init__(self, simulation, quasi_static=False, newton_tolerance=1e-6, max_newton_iterations=30,
                 max_cg_iterations=2000):
        model = simulation.model
        if model.relaxation is not None:
            raise ValueError("solver.integrator: the implicit and quasi-static integrators do not "
                             "support material.relaxation yet (its internal variables advance once a "
                             "step); use integrator 'explicit' or no relaxation")
        if not (math.isfinite(newton_tolerance) and 0 < newton_tolerance < 1):
            raise ValueError(f'newton_tolerance = {newton_tolerance!r}: expected a relative residual in (0, 1)')
        self.sim = simulation
        self.quasi_static = bool(quasi_static)
        self.newton_tolerance = float(newton_tolerance)
        self.max_newton_iterations = int(max_newton_iterations)
        self.max_cg_iterations = int(max_cg_iterations)
        n = model.mesh.n_nodes
        self._vectors = {name: np.zeros((n, 3)) for name in (
            'u0', 'x', 'v', 'force', 'residual', 'trial', 'trial_v', 'trial_force', 'trial_residual',
            'direction', 'search', 'z', 'product', 'probe', 'probe_v', 'probe_force', 'cg_residual',
            'tangent_base', 'best')}
        # the threshold switches an element's force between two laws: a jump that a difference
        # across it turns into an arbitrary 'stiffness'. The tangent is taken without it (every
        # element non-linear: the same tangent to O(|H|) where both agree), the residual with it.
        self._smooth_tangent = model.nonlinearity_threshold > 0 and (model.geometric or model.physical)
        self._pseudo_step = None            # its pseudo time step while it runs (None: Newton)
        self._diagonal_key = None
        self.newton_iterations = 0          # of the last step
        self.cg_iterations = 0              # of the last step, all Newton iterations together
        self.reset_counts()
        self.bonds = BondSet()              # the needles' bonded contacts, held inside the step

    def reset_counts(self):
        """The counts since the start (Simulation.reset: its warm-up step is not counted)."""
        self.stalled_steps = 0              # steps kept close to their goal (no descent, or the limit)
        self.continued_steps = 0            # steps that went on by pseudo-transient continuation
        self.force_evaluations = 0          # all steps, and their iterations together
        self.steps = 0
        self.total_newton_iterations = 0
        self.total_cg_iterations = 0

    def summary(self) -> str:
        """One line on the solves so far: iterations a step, stalls and continuations."""
        name = 'quasi-static' if self.quasi_static else 'implicit (backward Euler)'
        steps = max(self.steps, 1)
        return (f'{name}: {self.steps} steps, {self.total_newton_iterations / steps:.1f} Newton and '
                f'{self.total_cg_iterations / steps:.0f} conjugate-gradient iterations a step '
                f'({self.force_evaluations} element passes); {self.stalled_steps} kept as stalls (residual '
                f'within {STALL_TOLERANCE:g} of the forces, or of the jump at the non-linearity threshold), '
                f'{self.continued_steps} went on by continuation')

    # -- the pieces -------------------------------------------------------------------------------
    def constraint_compliance(self):
        """(inverse mass (n, 3), force scale (n,)) for the needle's constraints: each DOF's
        compliance over this step (module docstring) and 1, in the explicit solver's form."""
        self._update_diagonals()
        return self.constraint_inverse_mass, self._unit_scale

    def _update_diagonals(self):
        """Stiffness and viscous diagonals (rest state), the inertia per DOF over dt^2 and the
        preconditioner; rebuilt when the masses, the elements or dt change."""
        sim, model = self.sim, self.sim.model
        key = (sim.mass_version, model.topology_version, sim.dt)
        if key == self._diagonal_key:
            return
        n = model.mesh.n_nodes
        stiffness = stiffness_diagonal(model.tetrahedra, model.shape_gradients, model.volume_lambda,
                                       model.volume_mu, n)
        viscous = (stiffness_diagonal(model.tetrahedra, model.shape_gradients, model.viscous_lambda,
                                      model.viscous_mu, n) if model.viscous else np.zeros((n, 3)))
        dt = sim.dt
        mass = np.zeros(n) if self.quasi_static else sim.mass
        self._inertia = np.repeat((mass * (1.0 + dt * sim.damping_rate) / (dt * dt))[:, None], 3, axis=1)
        self._momentum_scale = np.repeat((mass / dt)[:, None], 3, axis=1)     # m / dt: m v_n / dt
        self._free = (sim.dof_kind == 0).astype(float)
        jacobi = self._inertia + stiffness + viscous / dt
        self._inverse_diagonal = np.where(jacobi > 0, 1.0 / np.where(jacobi > 0, jacobi, 1.0), 0.0) * self._free
        self._elastic_diagonal = (stiffness + viscous / dt) * self._free   # the continuation's shift per unit
        self._shift = self._inertia.copy()      # J's diagonal term: the inertia (+ the continuation's)
        # the compliance each DOF offers a constraint over this step (module docstring): the
        # preconditioner's diagonal is its stiffness over dt^2
        self.constraint_inverse_mass = self._inverse_diagonal / (dt * dt)
        self._unit_scale = np.ones(n)
        size = float(np.ptp(model.mesh.rest_positions, axis=0).max())
        # a residual this small is a displacement of 1e-12 body sizes against the stiffest DOF
        self._absolute_tolerance = 1e-12 * size * float(stiffness.max())
        self._perturbation = 1e-8 * size
        self._element_jumps = None
        if self._smooth_tangent:
            # the force each element's switch across the threshold makes: P_nonlinear - P_linear is
            # O((lambda + 2 mu) t^2) at |H| = t, on the element's faces (V |a_j| ~ V^(2/3)); twice that
            self._element_jumps = (2.0 * model.nonlinearity_threshold ** 2
                                   * (model.volume_lambda + 2.0 * model.volume_mu) / np.cbrt(model.volumes))
        self._diagonal_key = key

    def _forces(self, x, v, out, smooth=False):
        """out = f(x, v), the internal force (elastic + viscous, and the foundations') at displacement x, velocity v;
        ``smooth``: without the non-linearity threshold (every element non-linear)."""
        model = self.sim.model
        model.accumulate_forces(x, v, time_step=None, threshold_squared=0.0 if smooth else None)
        forces.reduce_buffers(*model.force_buffers, out)
        self.sim.add_support_forces(x, out)
        self.force_evaluations += 1

    def _unbalanced(self, x, force, out):
        """out = m (v - v_n) / dt + gamma v - f - f_ext at x (v = (x - u_n) / dt), every DOF."""
        sim = self.sim
        np.subtract(x, self._vectors['u0'], out=out)
        out *= self._inertia                    # (m / dt^2 + gamma / dt) (x - u_n)
        out -= self._momentum_scale * sim.velocity
        out -= force
        out -= sim.external_forces

    def _residual(self, x, v, force, out):
        """out = the free DOFs' residual (module docstring) at x, with v = (x - u_n) / dt and the
        internal force ``force`` already evaluated there; returns its norm."""
        self._unbalanced(x, force, out)
        out *= self._free
        if self.bonds:
            self.bonds.remove_reactions(out, self._inverse_diagonal)
        return math.sqrt(float(np.vdot(out, out)))

    def _evaluate(self, x, v, force, residual):
        np.subtract(x, self._vectors['u0'], out=v)
        v /= self.sim.dt
        self._forces(x, v, force)
        return self._residual(x, v, force, residual)

    def _apply(self, w, out):
        """out = J w (module docstring), Df by a forward difference of the element pass."""
        vec, dt = self._vectors, self.sim.dt
        scale = float(np.abs(w).max())
        if scale == 0.0:
            out[:] = 0.0
            return
        h = self._perturbation / scale
        probe, probe_v = vec['probe'], vec['probe_v']
        np.multiply(w, h, out=probe)
        np.multiply(probe, 1.0 / dt, out=probe_v)
        probe += vec['x']
        probe_v += vec['v']
        self._forces(probe, probe_v, vec['probe_force'], smooth=self._smooth_tangent)
        np.subtract(vec['probe_force'], vec['tangent_base'], out=out)
        out *= -1.0 / h
        out += self._shift * w
        out *= self._free

    def _solve(self, rhs, tolerance, out):
        """Preconditioned conjugate gradient for J out = rhs on the free DOFs, to |r| <= tolerance;
        returns the iterations. Stops early on a direction of non-positive curvature (the
        material's tangent lost definiteness), keeping what it has, and when the residual has
        not reached a new low for STAGNATION iterations, keeping the iterate with the lowest: the
        products are differences of the element pass, whose rounding sets a floor (below it the
        residual grows again, and every Newton iteration would run to the iteration cap)."""
        vec = self._vectors
        r, z, p, q = vec['cg_residual'], vec['z'], vec['search'], vec['product']
        best, best_norm, best_k = vec['best'], math.inf, 0
        out[:] = 0.0
        r[:] = rhs
        self._precondition(r, z)
        p[:] = z
        rz = float(np.vdot(r, z))
        for k in range(1, self.max_cg_iterations + 1):
            self._apply(p, q)
            curvature = float(np.vdot(p, q))
            if curvature <= 0.0:
                if k == 1:
                    out[:] = z
                return k
            alpha = rz / curvature
            out += alpha * p
            r -= alpha * q
            if self.bonds:    # keep r free of the bonds' part: it drifts there (Gould et al. 2001, sec. 6)
                self.bonds.remove_reactions(r, self._inverse_diagonal)
            norm = math.sqrt(float(np.vdot(r, r)))
            if norm <= tolerance:
                return k
            if norm < 0.99 * best_norm:
                best[:], best_norm, best_k = out, norm, k
            elif k - best_k >= STAGNATION:
                out[:] = best
                return k
            self._precondition(r, z)
            rz_next = float(np.vdot(r, z))
            if not rz_next > 0.0:     # r M^-1 r underflowed (|r| near 1e-160): nothing is left to reduce
                return k
            p *= rz_next / rz
            p += z
            rz = rz_next
        if best_norm < norm:
            out[:] = best
        return self.max_cg_iterations

    def _precondition(self, r, z):
        """z = D^-1 r, projected to keep the bonds (implicit_bonds)."""
        np.multiply(self._inverse_diagonal, r, out=z)
        if self.bonds:
            self.bonds.project(z, self._inverse_diagonal)

    def _line_search(self, x, norm):
        """Backtracking on |R| along Newton's direction: the full step unless it fails to reduce
        the residual, halved down to 1/64. Leaves the point in the trial vectors; returns its |R|."""
        vec = self._vectors
        step = 1.0
        while True:
            np.multiply(vec['direction'], step, out=vec['trial'])
            vec['trial'] += x
            trial_norm = self._evaluate(vec['trial'], vec['trial_v'], vec['trial_force'], vec['trial_residual'])
            if trial_norm <= (1.0 - 1e-4 * step) * norm:
                return trial_norm
            if step < 1.0 / 64:       # no descent; a point that is not finite is none either
                return trial_norm if math.isfinite(trial_norm) else math.inf
            step *= 0.5

    def _set_pseudo_step(self, pseudo_step):
        """Newton's matrix J (None) or J + D / pseudo_step, D the rest stiffness's diagonal."""
        self._pseudo_step = pseudo_step
        np.copyto(self._shift, self._inertia)
        if pseudo_step is not None:
            self._shift += self._elastic_diagonal / pseudo_step

    def _continue(self, x, norm):
        """One iteration of pseudo-transient continuation (Kelley & Keyes, SIAM J. Numer. Anal. 35,
        1998): the direction solved with J + D / delta is taken whole; the pseudo step delta
        grows as the residual falls (switched evolution relaxation, delta |R| held), so the
        iteration follows the residual's gradient flow where Newton's matrix is indefinite and
        becomes Newton's again near the root, which it shares. A residual that grows more than
        CONTINUATION_GROWTH-fold is refused and delta cut 10x. Returns the trial's |R|, or None
        when refused."""
        vec = self._vectors
        np.add(x, vec['direction'], out=vec['trial'])
        trial_norm = self._evaluate(vec['trial'], vec['trial_v'], vec['trial_force'], vec['trial_residual'])
        if not trial_norm <= CONTINUATION_GROWTH * norm:
            self._set_pseudo_step(0.1 * self._pseudo_step)
            return None
        self._set_pseudo_step(self._pseudo_step * norm / max(trial_norm, 1e-300))
        return trial_norm

    def threshold_floor(self, x):
        """The largest force jump [N] of the elements at the non-linearity threshold at x (|H|
        within THRESHOLD_BAND of it; module docstring), 0 if none is: a residual under it may
        have no root to reach."""
        if self._element_jumps is None:
            return 0.0
        model = self.sim.model
        corners = x[model.tetrahedra]                                   # (m, 4, 3)
        gradient = np.einsum('mkr,mkc->mrc', corners[:, 1:] - corners[:, :1], model.shape_gradients)
        norms = np.sqrt(np.einsum('mrc,mrc->m', gradient, gradient))
        threshold = model.nonlinearity_threshold
        near = np.abs(norms - threshold) <= THRESHOLD_BAND * threshold
        return float(self._element_jumps[near].max()) if near.any() else 0.0

    def _newton(self, x, v, force, residual, norm, first, goal, stall):
        """Newton's iteration from x (v, force, residual and |R| = norm evaluated there; first: the
        step's first |R|) to |R| <= goal, with continuation where it finds no descent (module
        docstring); updates them in place and returns the iterations. Raises SimulationDiverged."""
        sim, vec = self.sim, self._vectors
        iteration, limit = 0, self.max_newton_iterations
        while norm > goal:
            if iteration >= limit and (norm <= stall or norm <= self.threshold_floor(x)):
                self.stalled_steps += 1     # close enough, as a stall: the differenced tangent's floor
                break
            if iteration >= limit or not math.isfinite(norm):
                method = 'Newton' if self._pseudo_step is None else 'Newton, then continuation,'
                sim._diverged(f'the {"quasi-static" if self.quasi_static else "implicit"} step did not '
                              f'converge: {method} residual {norm:.3g} N after {iteration} iterations '
                              f'(goal {goal:.3g} N)')
            iteration += 1
            eta = min(0.01, norm / first) if first > 0 else 0.01
            if self._smooth_tangent:
                self._forces(x, v, vec['tangent_base'], smooth=True)
            else:
                vec['tangent_base'][:] = force
            np.negative(residual, out=vec['trial_residual'])
            # no finer than a tenth of Newton's goal: below it the differenced products are noise
            self.cg_iterations += self._solve(vec['trial_residual'], max(eta * norm, 0.1 * goal), vec['direction'])
            if self._pseudo_step is not None:
                trial_norm = self._continue(x, norm)
                if trial_norm is None:
                    continue
            else:
                trial_norm = self._line_search(x, norm)
            if trial_norm > norm and self._pseudo_step is None:
                # no descent along Newton's direction: the residual is not smooth here (an element
                # at the threshold or the inversion safeguard's switch), or Newton's matrix is not
                # positive definite (elements crushed around a retracting needle). Close enough
                # is kept; otherwise continuation takes over.
                if norm <= stall or norm <= self.threshold_floor(x):
                    self.stalled_steps += 1
                    break
                self.continued_steps += 1
                self._set_pseudo_step(CONTINUATION_START)
                limit = iteration + CONTINUATION_ITERATIONS
                continue
            x[:], v[:], force[:], residual[:] = vec['trial'], vec['trial_v'], vec['trial_force'], vec['trial_residual']
            norm = trial_norm
        return iteration

    # -- the step ---------------------------------------------------------------------------------
    def step(self, targets):
        """Advance the simulation's state by one step. ``targets``: (nodes, axes mask, (k, 3)
        displacement) of each prescribed set at the end of the step. Returns (work put in over the
        step [J], kinetic energy at its end [J]); raises SimulationDiverged when Newton fails."""
        sim = self.sim
        self._update_diagonals()
        vec, dt = self._vectors, sim.dt
        u0, x, v, force, residual = vec['u0'], vec['x'], vec['v'], vec['force'], vec['residual']
        u0[:] = sim.displacement
        np.multiply(sim.velocity, dt * self._free, out=x)     # predictor: the last velocity held
        x += u0
        for nodes, axes, target in targets:
            for r in np.flatnonzero(axes):
                x[nodes, r] = target[:, r]
        self.bonds.set([rows for coupling in sim.couplings for rows in coupling.implicit_bonds()],
                       self._inverse_diagonal, self._diagonal_key, sim.model.mesh.n_nodes)
        if self.bonds:
            self.bonds.satisfy(sim.model.mesh.rest_positions, x, self._inverse_diagonal)
        norm = self._evaluate(x, v, force, residual)
        first = norm
        scale = max(first, math.sqrt(float(np.vdot(force, force))),
                    math.sqrt(float(np.vdot(sim.external_forces, sim.external_forces))))
        goal = max(self.newton_tolerance * scale, self._absolute_tolerance)
        # below this a residual is kept as a stall: the differenced tangent's floor (and below the
        # jump of an element at the non-linearity threshold: threshold_floor)
        stall = STALL_TOLERANCE * scale
        self.cg_iterations = 0
        self._set_pseudo_step(None)
        try:
            iteration = self._newton(x, v, force, residual, norm, first, goal, stall)
        finally:       # J's shift is Newton's again for whoever applies J next
            self._set_pseudo_step(None)
        self.newton_iterations = iteration
        self.steps += 1
        self.total_newton_iterations += iteration
        self.total_cg_iterations += self.cg_iterations
        largest = float(np.abs(x).max())
        if largest >= sim.displacement_limit:
            sim._diverged(f'a displacement reached {largest:.3g} m, past {sim.displacement_limit:.3g} m '
                          '(100 body sizes)')
        # the state at the end of the step; the prescribed DOFs' reaction does work on the tissue
        reaction, moved = vec['trial_residual'], vec['trial']
        self._unbalanced(x, force, reaction)     # zero on free DOFs, the constraint's force on held ones
        if self.bonds:                           # and on bonded ones: the bonds' multipliers
            self.bonds.write_forces(reaction * self._free, self._inverse_diagonal)
        np.subtract(x, u0, out=moved)
        work = float(np.vdot(sim.external_forces, moved)) + float(np.vdot(reaction, moved))
        sim.displacement[:] = x
        sim.velocity[:] = v
        sim.internal_force[:] = force
        kinetic = 0.0 if self.quasi_static else 0.5 * float(np.vdot(sim.mass[:, None] * v, v))
        return work, kinetic
