"""Explicit time integration of the lumped-mass tensor-mass model, with a stability watchdog.

Each node obeys m_i a_i + gamma_i v_i - f_i(u, v) = f_ext,i (docs/method.md). We integrate with
symplectic (semi-implicit) Euler, velocity first:

    v_{n+1} = (v_n + dt (f_n + f_ext) / m) / (1 + dt gamma / m),   u_{n+1} = u_n + dt v_{n+1}

The damping term is taken implicitly, so it never lowers the stable step; the elastic part is
explicit and stable below dt_crit = 2 / omega_max (see TensorMassModel.critical_time_step).
Degrees of freedom are free, fixed, or prescribed (a displacement given as a function of time),
per node and per axis, so a frictionless plate can drive z alone.
"""
import math
import time

import numpy as np
from numba import njit, prange

from tissue_sim_ros.engine.model.kernels import FASTMATH, take_node_force
from tissue_sim_ros.engine.solver.implicit import INTEGRATORS, ImplicitStep
from tissue_sim_ros.errors import SimulationDiverged

FREE, FIXED, PRESCRIBED = 0, 1, 2
_AXES = {'x': 0, 'y': 1, 'z': 2}


@njit(cache=True, parallel=True, fastmath=FASTMATH, boundscheck=False, nogil=True)
def _advance_free(displacement, velocity, buffers, chunk_node_lo, chunk_node_hi, force, external,
                  inverse_mass, damping_rate, dof_kind, dt, displacement_limit, support_rows, support_stiffness):
    """Gather each node's force from the element pass's buffers (into ``force``) and advance its
    free DOFs by symplectic Euler, with the foundations' force -K_i u_i of the nodes they hold
    (``support_rows`` (n,): the node's row of ``support_stiffness`` (r, 6), -1 for none;
    supports.py); returns (external work, kinetic energy, count of components that are not
    finite or whose displacement exceeds ``displacement_limit``)."""
    work = 0.0
    kinetic = 0.0
    bad = 0
    for i in prange(displacement.shape[0]):
        force[i, 0], force[i, 1], force[i, 2] = take_node_force(buffers, chunk_node_lo, chunk_node_hi, i)
        inv_m = inverse_mass[i]
        damping_factor = 1.0 / (1.0 + dt * damping_rate[i])
        sx, sy, sz = 0.0, 0.0, 0.0
        row = support_rows[i]
        if row >= 0:
            k = support_stiffness[row]
            ux, uy, uz = displacement[i, 0], displacement[i, 1], displacement[i, 2]
            sx = -(k[0] * ux + k[3] * uy + k[4] * uz)
            sy = -(k[3] * ux + k[1] * uy + k[5] * uz)
            sz = -(k[4] * ux + k[5] * uy + k[2] * uz)
        for r in range(3):
            if dof_kind[i, r] == FREE:
                v_old = velocity[i, r]
                support = sx if r == 0 else (sy if r == 1 else sz)
                v = (v_old + dt * inv_m * (force[i, r] + support + external[i, r])) * damping_factor
                velocity[i, r] = v
                displacement[i, r] += dt * v
                work += external[i, r] * dt * v
                v_mid = 0.5 * (v + v_old)          # velocity at the time of the forces
                kinetic += 0.5 * v_mid * v_mid / inv_m
                if not (abs(displacement[i, r]) < displacement_limit and abs(v) < np.inf):
                    bad += 1
    return work, kinetic, bad


@njit(cache=True)
def _apply_prescribed(nodes, axes, targets, displacement, velocity, force, external, mass, dt):
    """Move prescribed DOFs to their targets; return the work the constraint did on the tissue.

    The constraint force r closes m a = f + f_ext + r, so its work over the step is r . du.
    """
    work = 0.0
    kinetic = 0.0
    for j in range(nodes.shape[0]):
        i = nodes[j]
        for r in range(3):
            if axes[r]:
                step = targets[j, r] - displacement[i, r]
                v_new = step / dt
                reaction = mass[i] * (v_new - velocity[i, r]) / dt - force[i, r] - external[i, r]
                work += reaction * step
                v_mid = 0.5 * (v_new + velocity[i, r])
                velocity[i, r] = v_new
                displacement[i, r] = targets[j, r]
                kinetic += 0.5 * mass[i] * v_mid * v_mid
    return work, kinetic


class _Prescribed:
    def __init__(self, nodes, axes, displacement_at):
        self.nodes = nodes
        self.axes = axes
        self.displacement_at = displacement_at
        self.targets = np.zeros((len(nodes), 3))


def _node_indices(nodes, n_nodes, field):
    nodes = np.asarray(nodes)
    if nodes.dtype == bool:
        if nodes.shape != (n_nodes,):
            raise ValueError(f'{field}: a boolean mask must have shape ({n_nodes},), got {nodes.shape}')
        return np.flatnonzero(nodes)
    nodes = nodes.astype(np.int64).ravel()
    bad = nodes[(nodes < 0) | (nodes >= n_nodes)]
    if bad.size:
        raise ValueError(f'{field}: node indices {bad[:10].tolist()} out of range [0, {n_nodes})')
    return nodes


def _axes_mask(axes, field):
    if not axes or set(axes) - set(_AXES):
        raise ValueError(f"{field}: axes = {axes!r}; expected a non-empty combination of 'x', 'y', 'z'")
    mask = np.zeros(3, dtype=np.bool_)
    for a in axes:
        mask[_AXES[a]] = True
    return mask


class Simulation:
    """Explicit dynamics of a TensorMassModel with constraints, external forces and a watchdog.

    damping: mass-proportional damping rate [1/s] (gamma_i = damping * m_i), or an (n,) array
    of gamma_i [kg/s]. fixed: nodes fixed on all axes (indices or boolean mask). dt: time step
    [s]; None picks ``time_step_safety`` times the critical step estimate. mass_scaling: factor
    (>= 1) on every node mass, for quasi-static runs: the critical step grows as its square
    root, inertial forces grow by it (measure what that costs before relying on it).
    :meth:`scale_selected_masses` adds mass only where the smallest elements limit the step.
    """

    def __init__(self, model, *, damping=0.0, fixed=None, dt=None, time_step_safety=0.8,
                 check_interval=50, energy_growth_factor=2.0, allow_inverted=False, mass_scaling=1.0,
                 integrator='explicit', newton_tolerance=1e-6):
        self.model = model
        if integrator not in INTEGRATORS:
            raise ValueError(f'integrator = {integrator!r}: expected one of {", ".join(INTEGRATORS)}')
        self.integrator = integrator
        if integrator != 'explicit' and getattr(model, 'precision', 'float64') != 'float64':
            raise ValueError(f'solver.integrator = {integrator!r} needs model.precision = float64, got '
                             f'{model.precision!r}: its Newton tangent differences forces 1e-8 of the body '
                             f'size apart, below float32 arithmetic\'s resolution (1e-7)')
        if not (isinstance(mass_scaling, (int, float)) and math.isfinite(mass_scaling) and mass_scaling >= 1.0):
            raise ValueError(f'mass_scaling = {mass_scaling!r}: expected a finite factor >= 1')
        self.mass_scaling = float(mass_scaling)
        n = model.mesh.n_nodes
        self.dof_kind = np.zeros((n, 3), dtype=np.int8)
        #: the foundations (supports.py): each node's row of support_stiffness (-1: none)
        self.support_rows = np.full(n, -1, dtype=np.int64)
        self.support_stiffness = np.zeros((0, 6))
        #: constant loads (gravity) a reset puts back in external_forces; the state a reset
        #: returns to (None: rest)
        self.body_forces = np.zeros((n, 3))
        self.initial_displacement = None
        #: selective mass scaling's factor on each node's mass, on top of mass_scaling
        self.node_mass_factor = np.ones(n)
        self._update_masses()
        damping_arr = np.asarray(damping, dtype=float)
        if damping_arr.ndim == 0:
            if not (math.isfinite(float(damping_arr)) and damping_arr >= 0):
                raise ValueError(f'damping = {float(damping_arr)!r}: expected a finite rate >= 0 [1/s]')
            self.damping_rate = np.full(n, float(damping_arr))
        else:
            if damping_arr.shape != (n,) or not np.all(np.isfinite(damping_arr)) or np.any(damping_arr < 0):
                raise ValueError(f'damping: expected a rate >= 0 [1/s] or ({n},) finite gamma >= 0 [kg/s]')
            self.damping_rate = damping_arr * self.inverse_mass
        self._prescribed = []
        if fixed is not None:
            self.fix(fixed)
        self._critical = None
        self.time_step_safety = float(time_step_safety) if dt is None else None  # None: dt fixed
        if dt is None:
            dt = time_step_safety * self.critical_time_step()
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise ValueError(f'dt = {dt!r}: expected a finite time step > 0 s')
        self.dt = float(dt)
        self._implicit = None if integrator == 'explicit' else ImplicitStep(
            self, quasi_static=integrator == 'quasi_static', newton_tolerance=newton_tolerance)
        self.check_interval = int(check_interval)
        self.energy_growth_factor = float(energy_growth_factor)
        self.allow_inverted = allow_inverted
        # a displacement of 100 body sizes is a blow-up even between two energy checks (a
        # St Venant-Kirchhoff run can grow from normal to 1e38 m within a few steps)
        self.displacement_limit = 100.0 * float(np.ptp(model.mesh.rest_positions, axis=0).max())
        total_stiffness = float(np.sum(model.volume_lambda + 2.0 * model.volume_mu))
        self.energy_floor = 1e-12 * total_stiffness   # energy of a strain of 1e-6
        self.displacement = np.zeros((n, 3))
        self.velocity = np.zeros((n, 3))
        self.internal_force = np.zeros((n, 3))
        self.external_forces = np.zeros((n, 3))
        # CPU time of the calling thread in the force kernel (element pass + node update), all
        # steps: with more numba threads, theirs is not in it (about this times the threads)
        self.kernel_s = 0.0
        # objects whose implicit_bonds() the implicit integrators hold inside each step (needles)
        self.couplings = []
        self.reset()
        self._warm_up()

    def _warm_up(self):
        """Compile (or load from numba's cache) the step kernels at start-up: one step from rest
        with no input changes nothing, then the state is reset. On a first start a second process
        may be compiling them (engine.compiled.cache): wait for it, then they load."""
        from tissue_sim_ros.engine.compiled import cache as compile_cache
        compile_cache.wait_for_helper()
        saved = self._prescribed
        self._prescribed = []
        self.step()
        self._prescribed = saved
        self.reset()

    def _update_masses(self):
        """Lumped masses from the model's current elements; nodes left without mass are held.
        ``added_mass``: what the scalings add to each node (the inertia estimate's)."""
        physical = self.model.lumped_masses()
        self.mass = self.mass_scaling * self.node_mass_factor * physical
        self.added_mass = self.mass - physical
        massless = self.mass <= 0.0
        self.inverse_mass = np.where(massless, 0.0, 1.0 / np.where(massless, 1.0, self.mass))
        self.dof_kind[massless] = FIXED
        self._topology_version = self.model.topology_version
        # what depends on the masses or on which DOFs are free (compliances, the implicit
        # solve's diagonals) rebuilds when this changes
        self.mass_version = getattr(self, 'mass_version', -1) + 1

    # -- set-up -------------------------------------------------------------------------------
    def fix(self, nodes, axes='xyz'):
        """Hold the given nodes' displacement at zero along ``axes``."""
        idx = _node_indices(nodes, self.model.mesh.n_nodes, 'fixed')
        self.dof_kind[np.ix_(idx, np.flatnonzero(_axes_mask(axes, 'fixed')))] = FIXED
        self.mass_version += 1          # the held DOFs changed: what depends on them rebuilds

    def set_supports(self, rows, stiffness):
        """Hold nodes by elastic foundations: ``rows`` (n,) each node's row of ``stiffness`` (r,
        6) (-1: none), the symmetric K_i as xx, yy, zz, xy, xz, yz [N/m] (supports.py)."""
        rows = np.asarray(rows, dtype=np.int64)
        stiffness = np.ascontiguousarray(stiffness, dtype=np.float64).reshape(-1, 6)
        if rows.shape != self.support_rows.shape or rows.max(initial=-1) >= len(stiffness) \
                or not np.isfinite(stiffness).all():
            raise ValueError(f'supports: rows must be ({len(self.support_rows)},) indices into finite (r, 6) stiffness')
        self.support_rows, self.support_stiffness = rows, stiffness
        self._critical = None

    def set_body_forces(self, forces):
        """Constant loads [N] (n, 3) (gravity: m_i g with the unscaled masses), in external_forces
        now and after each reset (Scene.reset)."""
        self.body_forces = np.array(forces, dtype=float).reshape(self.displacement.shape)
        np.copyto(self.external_forces, self.body_forces)

    def set_initial_state(self, displacement):
        """The displacement a reset returns to (a settled state), at rest; set now."""
        self.initial_displacement = None if displacement is None else np.array(displacement, dtype=float)
        self.reset()

    def add_support_forces(self, displacement, out):
        """out += the foundations' forces -K_i u_i at ``displacement`` (the implicit steps' force)."""
        if len(self.support_stiffness):
            from tissue_sim_ros.engine.solver.supports import add_support_forces
            add_support_forces(self.support_rows, self.support_stiffness, displacement, out)

    def prescribe(self, nodes, displacement_at, axes='xyz'):
        """Drive nodes along ``axes``: displacement_at(t) gives (3,) or (k, 3) metres at time t."""
        idx = _node_indices(nodes, self.model.mesh.n_nodes, 'prescribed')
        mask = _axes_mask(axes, 'prescribed')
        self.dof_kind[np.ix_(idx, np.flatnonzero(mask))] = PRESCRIBED
        self._prescribed.append(_Prescribed(idx, mask, displacement_at))
        self.mass_version += 1

    def rescale_masses(self, mass_scaling):
        """Change the mass scaling at run time (the node's degradation ladder, a prediction's
        rung): node masses scale by ``mass_scaling`` / the current one and the time step by its
        square root, so the step keeps its fraction of the critical step (which grows as
        sqrt(mass)). The damping force is kept: the rate falls by the same ratio, so gamma_i =
        m_i rate_i is the one the scene was set up (and calibrated) with and only the added
        inertia changes the response. Scaled with the masses, the mass-proportional damping would
        dominate the change (on the default insertion at x16 it would move the axial force three
        times as far as the added inertia alone does). Velocities are kept; the kinetic energy this
        changes counts as work put in (the watchdog's budget)."""
        if not (isinstance(mass_scaling, (int, float)) and math.isfinite(mass_scaling) and mass_scaling >= 1.0):
            raise ValueError(f'mass_scaling = {mass_scaling!r}: expected a finite factor >= 1')
        ratio = float(mass_scaling) / self.mass_scaling
        kinetic = 0.5 * float(np.sum(self.mass[:, None] * self.velocity ** 2))
        self.mass_scaling = float(mass_scaling)
        self._update_masses()
        self.damping_rate /= ratio
        self.input_work += (ratio - 1.0) * kinetic
        self.dt *= math.sqrt(ratio)
        self._critical = None

    def scale_selected_masses(self, factor) -> float:
        """Selective mass scaling: the critical step's elastic part raised at least ``factor``-fold
        (>= 1) by mass added only at the nodes of the elements whose own step is shortest
        (critical_step.selective_mass_factors; why it costs little mass on a mesher's organ); a
        step set by time_step_safety follows. The damping rate is kept, as with mass_scaling. Returns
        ``selective_added_fraction``."""
        from tissue_sim_ros.engine.model.critical_step import selective_mass_factors
        if not (isinstance(factor, (int, float)) and math.isfinite(factor) and factor >= 1.0):
            raise ValueError(f'selective mass scaling factor = {factor!r}: expected a finite factor >= 1')
        if factor > 1.0:
            self.node_mass_factor = selective_mass_factors(self.model, factor, self.node_mass_factor)
            self._update_masses()
            self._critical = None
            if self.time_step_safety is not None:
                self.dt = self.time_step_safety * self.critical_time_step()
        return self.selective_added_fraction

    @property
    def selective_added_fraction(self) -> float:
        """The mass selective scaling added, over the (uniformly scaled) total without it."""
        physical = self.model.lumped_masses()
        total = float(np.sum(physical))
        return float(np.sum((self.node_mass_factor - 1.0) * physical)) / total if total > 0.0 else 0.0

    def advance_arguments(self):
        """The arguments of the node update ``_advance_free`` after the element pass (the explicit
        step's, and a compiled substep's, engine.compiled.substeps)."""
        return (self.displacement, self.velocity, *self.model.force_buffers, self.internal_force,
                self.external_forces, self.inverse_mass, self.damping_rate, self.dof_kind, self.dt,
                self.displacement_limit, self.support_rows, self.support_stiffness)

    @property
    def has_prescribed(self):
        """Whether any DOF is driven (``prescribe``)."""
        return bool(self._prescribed)

    def constraint_compliance(self):
        """(inverse mass (n, 3) of each DOF, 0 for held ones; force scale (n,)): how a constraint
        applied after a step (the needle's) moves a DOF and what force that takes, f = scale dx /
        (inverse mass dt^2). Explicit: the lumped mass and 1 + dt gamma / m (the damping is
        implicit in the update); the implicit integrators: their own (implicit.ImplicitStep)."""
        if self._implicit is not None:
            return self._implicit.constraint_compliance()
        return np.where(self.dof_kind == 0, self.inverse_mass[:, None], 0.0), 1.0 + self.dt * self.damping_rate

    def implicit_summary(self) -> str:
        """The implicit integrators' line on their solves so far ('' for the explicit one)."""
        return '' if self._implicit is None else self._implicit.summary()

    def critical_time_step(self):
        """Estimated critical (largest stable) time step [s] of the linearised model, cached.

        Elastic limit 2 / omega_max (TensorMassModel.critical_time_step, masses scaled). The
        Kelvin-Voigt force is explicit too: with C <= tau K (tau the largest ratio lambda_v /
        lambda, mu_v / mu over the elements), the central-difference limit of a damped mode is
        dt = (2 / omega) (sqrt(1 + zeta^2) - zeta), zeta = omega tau / 2, smallest at omega_max.
        """
        if self._critical is None:
            factor = None if np.all(self.node_mass_factor == 1.0) else self.node_mass_factor
            elastic = self.model.critical_time_step(mass_factor=factor) * math.sqrt(self.mass_scaling)
            supported = np.flatnonzero(self.support_rows >= 0)
            if len(supported):       # lambda_max(M^-1 (K + K_s)) <= omega^2 + max_i |K_i|_inf / m_i
                rows = np.abs(self.support_stiffness[self.support_rows[supported]])
                bound = np.max(np.stack([rows[:, 0] + rows[:, 3] + rows[:, 4], rows[:, 3] + rows[:, 1] + rows[:, 5],
                                         rows[:, 4] + rows[:, 5] + rows[:, 2]]), axis=0)
                omega_squared = (2.0 / elastic) ** 2 + float(np.max(bound * self.inverse_mass[supported]))
                elastic = 2.0 / math.sqrt(omega_squared)
            tau = self.model.viscous_time_constant()
            omega = 2.0 / elastic
            zeta = 0.5 * omega * tau
            self._critical = elastic * (math.sqrt(1.0 + zeta * zeta) - zeta)
        return self._critical

    def reset(self):
        """Back to the rest state at t = 0 (the model's relaxation history forgotten too)."""
        self.model.reset_relaxation()
        if getattr(self, 'initial_displacement', None) is None:
            self.displacement[:] = 0.0
        else:
            self.displacement[:] = self.initial_displacement
        self.velocity[:] = 0.0
        self.internal_force[:] = 0.0
        self.time = 0.0
        self.step_count = 0
        self.input_work = 0.0
        self.kinetic_energy = 0.0
        self.reference_energy = None   # measured at the first step, after any initial state is set
        self.safeguarded_elements = 0
        self.max_safeguarded_elements = 0
        if self._implicit is not None:
            self._implicit.reset_counts()

    # -- stepping -------------------------------------------------------------------------------
    def step(self, n_steps=1):
        """Advance ``n_steps`` time steps; raises SimulationDiverged when the watchdog trips."""
        model, dt = self.model, self.dt
        if model.topology_version != self._topology_version:   # elements were cut away or added
            self._update_masses()
        if self.reference_energy is None:
            self.reference_energy = sum(self.energy())
        for _ in range(n_steps):
            check = (self.step_count + 1) % self.check_interval == 0
            if check:   # energy at u_n, matched with the velocity at t_n from the advance
                strain, inverted = model.strain_energy(self.displacement)
                strain += self.support_energy()
            t_next = self.time + dt
            if self._implicit is not None:
                kernel0 = time.thread_time()
                for p in self._prescribed:
                    np.copyto(p.targets, p.displacement_at(t_next))
                work, kinetic = self._implicit.step([(p.nodes, p.axes, p.targets) for p in self._prescribed])
                self.kernel_s += time.thread_time() - kernel0
                bad = 0
                free_kinetic = kinetic
            else:
                kernel0 = time.thread_time()
                # the time since the previous step's forces (none before the first): the relaxation's
                # internal variables advance over it
                model.accumulate_forces(self.displacement, self.velocity,
                                        time_step=dt if self.step_count else 0.0)
                work, kinetic, bad = _advance_free(*self.advance_arguments())
                self.kernel_s += time.thread_time() - kernel0
                free_kinetic = kinetic
                for p in self._prescribed:
                    np.copyto(p.targets, p.displacement_at(t_next))
                    w, k = _apply_prescribed(p.nodes, p.axes, p.targets, self.displacement, self.velocity,
                                             self.internal_force, self.external_forces, self.mass, dt)
                    work += w
                    kinetic += k
            self.input_work += work
            self.kinetic_energy = kinetic
            self.time = t_next
            self.step_count += 1
            if check:
                self.watch(bad, None)
                self._check_energy(strain, inverted)
            else:
                self.watch(bad, free_kinetic)

    def watch(self, bad, free_kinetic):
        """The watchdog after a step: raise SimulationDiverged for ``bad`` components (not
        finite, or past the displacement limit) or, unless None, free DOFs' kinetic energy above
        the limit (``_energy_limit``; a compiled substep, engine.compiled.substeps, tests the same)."""
        if bad:
            self._diverged(f'{bad} displacement or velocity components became NaN or infinite, '
                           f'or a displacement passed {self.displacement_limit:.3g} m (100 body sizes)')
        if free_kinetic is not None and not free_kinetic <= self._energy_limit():
            # every step, the free DOFs' kinetic energy alone (the step computes it anyway): an
            # unstable step's energy is half kinetic, so it is caught within a step or two of
            # crossing. Not the prescribed DOFs': a driver's motion is not the tissue's energy
            # (a driven relaxation cycle gives back its work while its nodes still move)
            self._diverged(f'energy grew without input: kinetic energy {free_kinetic:.4g} J above the '
                           f'{self._energy_limit():.4g} J a stable run can hold (initial energy '
                           f'{self.reference_energy:.4g} J plus work put in {self.input_work:.4g} J)')

    def _check_energy(self, strain, inverted):
        """Energy (kinetic at t_n + strain at u_n) against the initial energy plus the work put in.

        A stable explicit run's energy still swings by up to 1 / (1 - (dt / dt_crit)^2) (about 5x
        at 0.9 dt_crit: the discrete modes' kinetic/strain split), so the allowed growth is
        widened by that factor; a run above the limit grows exponentially and crosses it fast.
        """
        self.note_safeguarded()
        total = self.kinetic_energy + strain
        budget = self.reference_energy + max(self.input_work, 0.0)
        if not math.isfinite(total) or total > self._energy_limit():
            self._diverged(f'energy grew without input: kinetic + strain energy {total:.4g} J against '
                           f'{budget:.4g} J initial plus work put in')
        if inverted and self.refuses_inverted():
            self._diverged(f'{inverted} inverted elements (det F <= 0)')

    def note_safeguarded(self):
        """At an energy-check step: the elements the inversion safeguard changed in the step's
        force evaluation (reported, see TensorMassModel), and the most so far."""
        self.safeguarded_elements = self.model.safeguarded_count
        self.max_safeguarded_elements = max(self.max_safeguarded_elements, self.safeguarded_elements)

    def refuses_inverted(self):
        """Whether inverted elements at an energy-check step are a divergence: unless allowed, or
        the geometric model's inversion safeguard handles them."""
        return not self.allow_inverted and not (self.model.geometric and self.model.inversion_safeguard)

    def _energy_limit(self):
        """The most energy [J] a stable run can hold: the growth factor times the initial energy
        plus the work put in, widened by the discrete swing (the implicit integrators dissipate:
        none), plus a floor."""
        budget = self.reference_energy + max(self.input_work, 0.0)
        return self.energy_limit_factor() * budget + self.energy_floor

    def energy_limit_factor(self):
        """The growth factor times the discrete swing: the energy limit is this times (initial
        energy plus work put in) plus ``energy_floor``."""
        swing = 1.0 if self._implicit is not None else 1.0 / max(1.0 - (self.dt / self.critical_time_step()) ** 2, 0.05)
        return self.energy_growth_factor * swing

    def _diverged(self, reason):
        raise SimulationDiverged(reason, self.step_count, self.time, self.dt, self.critical_time_step())

    # -- outputs --------------------------------------------------------------------------------
    def reaction_force(self, nodes):
        """Total force (3,) [N] the tissue exerts on whatever holds ``nodes`` (sum of internal forces)."""
        return self.internal_force[_node_indices(nodes, self.model.mesh.n_nodes, 'nodes')].sum(axis=0)

    def energy(self):
        """(kinetic, strain) energy [J] of the current state (strain: the foundations' too)."""
        kinetic = 0.5 * float(np.sum(self.mass[:, None] * self.velocity ** 2))
        return kinetic, self.model.strain_energy(self.displacement)[0] + self.support_energy()

    def support_energy(self):
        """The foundations' stored energy [J] (supports.py)."""
        if not len(self.support_stiffness):
            return 0.0
        from tissue_sim_ros.engine.solver.supports import support_energy
        return support_energy(self.support_rows, self.support_stiffness, self.displacement)
