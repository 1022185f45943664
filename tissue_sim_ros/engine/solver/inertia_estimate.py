"""The error that mass scaling adds to the needle force, estimated while a run goes on.

Mass scaling s multiplies every node mass m_i, and with it the mass-proportional damping
gamma_i = c m_i (solver.damping_per_s c). For the same motion the tissue's equation
m a + gamma v = f + f_ext then carries s times the inertial and damping force of the unscaled
tissue, of which (1 - 1/s) is what the scaling added: body forces b_i = (1 - 1/s) m_i (a_i + c v_i)
(scaled masses). Selective mass scaling (Simulation.scale_selected_masses) gives each node its own
s_i; b_i = (m_i - m_i / s_i) (a_i + c v_i) covers both (Simulation.added_mass). How much of them
the needle feels follows from Betti's reciprocal theorem: with the needle a prescribed
displacement delta, body forces b change its reaction by sum_i b_i . psi_i,
psi the displacement field of a unit needle displacement. For a response linear in the needle's
push psi = u / delta, u the displacement now, so

    added axial force = sum_i b_i . u_i / delta,    delta = u_k . axis, k the node moved most along it.

The estimate is that force, smoothed (exponential average, time constant SMOOTHING_S), its rms
over the run relative to the range of the axial force: the force NRMSE that ``compare`` and
``chart`` measure. One pass over the nodes per advance (a_i over the advance), no allocation.

A puncture moves. A membrane ruptures at a force, and the scaled run carries the added force A
on top of the unscaled one's, so it reaches that force dt = A / (dF/dt) earlier, dF/dt the axial
force's rate as it loads. For that dt one run has dropped and the other not: their difference is
the drop D, which adds D^2 dt to the integral of the squared error. At each puncture the estimate
takes A and dF/dt as they were before it (both smoothed over SMOOTHING_S; the rate is not
followed during a drop) and D as the fall of the axial force within SMOOTHING_S after it. This is
the force criterion's shift (membrane.criterion: force, the default scene's); a membrane that
ruptures on its energy moves further, A x / F for the travel x since contact on a force F, which
the estimate does not model.

Why weighted and smoothed (test_inertia_estimate.py holds it against runs without mass scaling):
the plain momentum balance (all of b on the needle) reads several times the measured error,
because the walls carry most of it; the ringing, which the unscaled tissue has too, is not what
the scaling adds, and unsmoothed it would count. On the default scene (tissue_sim_ros.bench.inertia:
from 1 mm above the surface, 17 mm in at 5 mm/s or 14 mm at 3 mm/s, against the same scene
unscaled) the estimate is 0.79-0.85 of the measured error at s = 100, 400 and 1600, where the
capsule punctures 0.08-1.55 mm early. At s = 25 the puncture moves by less than a force sample's
20 ms and whether a sample falls in between decides the measured error; the estimate is its
expectation. It is first order: the scaled run's later path (the recoil after a puncture,
s x speed large) is not in it, and on a small sample whose membrane ruptures at 0.3 N the
recoil's accelerations make it read high at s = 25 and 100. Figures: docs/performance.md.
``solver.mass_scaling: auto`` measures instead
(:mod:`tissue_sim_ros.analysis.charting.mass_scaling_rule`).
"""
from __future__ import annotations

import math

from numba import njit

__all__ = ['SMOOTHING_S', 'InertiaEstimate', 'weighted_body_force', 'inertia_line']

#: time constant of the exponential average of the added force [s] (module docstring)
SMOOTHING_S = 0.1


@njit(cache=True, nogil=True)
def weighted_body_force(mass, damping_rate, velocity, previous_velocity, displacement, axis, elapsed):
    """(sum_i m_i (a_i + c_i v_i) . u_i, delta) with a_i = (v_i - previous_i) / elapsed, delta the
    axial displacement of the node moved most along ``axis``; copies ``velocity`` into
    ``previous_velocity``."""
    weighted = 0.0
    delta = 0.0
    for i in range(velocity.shape[0]):
        m = mass[i]
        c = damping_rate[i]
        along = 0.0
        for r in range(3):
            v = velocity[i, r]
            weighted += m * ((v - previous_velocity[i, r]) / elapsed + c * v) * displacement[i, r]
            previous_velocity[i, r] = v
            along += displacement[i, r] * axis[r]
        if abs(along) > abs(delta):
            delta = along
    return weighted, delta


class InertiaEstimate:
    """Running estimate of the force error that mass scaling adds (module docstring).

    ``update`` after each advance with the simulated time it covered, the needle's axis and
    axial force, and its punctures so far; ``error`` is the rms force error (the added force's and
    the moved punctures') over the range of the axial force (None before two updates or while the
    force has no range); ``rms_n`` in newtons; ``puncture_shifts_s`` each puncture's estimated
    shift in time.
    With mass scaling 1 everything stays 0. A change of the mass scaling (the node's ladder)
    restarts the acceleration, not the statistics.
    """

    def __init__(self):
        self.reset()

    def reset(self) -> None:
        self._previous = None
        self._mass_scaling = None
        self._smoothed = 0.0
        self._sum_squares = 0.0
        self._duration = 0.0
        self._low = math.inf
        self._high = -math.inf
        self._force = None              # the axial force at the last update
        self._rate = 0.0                # its smoothed rate [N/s]
        self._punctures = 0
        self._shift_squares = 0.0       # sum of D^2 dt of the punctures whose drop is over [N^2 s]
        self._pending = None            # [force before, lowest since, dt, time since] of the last puncture
        self.puncture_shifts_s = []     # each puncture's estimated shift in time [s]

    def update(self, simulation, elapsed: float, axis, axial_force: float, punctures: int = 0) -> None:
        """After an advance of ``elapsed`` simulated seconds: ``axis`` and ``axial_force`` of the
        needle, ``punctures`` the membranes it has punctured so far."""
        if simulation.integrator == 'quasi_static':    # no inertia: nothing scaled to estimate
            return
        self._low = min(self._low, axial_force)
        self._high = max(self._high, axial_force)
        self._follow_punctures(elapsed, axial_force, punctures)
        scaling, self._mass_scaling = self._mass_scaling, float(simulation.mass_scaling)
        if self._previous is None or self._previous.shape != simulation.velocity.shape:
            self._previous = simulation.velocity.copy()        # (re)start: no acceleration yet
            return
        if scaling != self._mass_scaling:
            self._previous[:] = simulation.velocity
            return
        if not elapsed > 0.0:
            return
        weighted, delta = weighted_body_force(simulation.added_mass, simulation.damping_rate, simulation.velocity,
                                              self._previous, simulation.displacement, axis, elapsed)
        added = weighted / delta if delta != 0.0 else 0.0
        if not math.isfinite(added):
            return
        self._smoothed += (added - self._smoothed) * -math.expm1(-elapsed / SMOOTHING_S)
        self._sum_squares += self._smoothed * self._smoothed * elapsed     # time-weighted
        self._duration += elapsed

    def _follow_punctures(self, elapsed: float, force: float, punctures: int) -> None:
        """The axial force's rate before a puncture, and the shift and drop of each (module
        docstring); A is the smoothed added force as it was before this advance."""
        if self._pending is not None:
            self._pending[1] = min(self._pending[1], force)
            self._pending[3] += elapsed
            if self._pending[3] >= SMOOTHING_S:
                self._shift_squares += self._drop_term()
                self._pending = None
        if punctures > self._punctures and self._force is not None:
            if self._pending is not None:            # a second puncture inside the first's window
                self._shift_squares += self._drop_term()
            shift = abs(self._smoothed) / self._rate if self._rate > 0.0 else 0.0
            shift = min(shift, self._duration)       # not before the run began
            self.puncture_shifts_s.append(shift)
            self._pending = [self._force, force, shift, elapsed]
        elif self._force is not None and elapsed > 0.0 and self._pending is None:
            # not while a drop is followed: the next puncture's shift wants the loading's rate
            rate = (force - self._force) / elapsed
            self._rate += (rate - self._rate) * -math.expm1(-elapsed / SMOOTHING_S)
        self._punctures = punctures
        self._force = force

    def _drop_term(self) -> float:
        before, lowest, shift, _ = self._pending
        return max(before - lowest, 0.0) ** 2 * shift

    @property
    def rms_n(self) -> float:
        """rms of the force error the scaling adds [N]: the added force's and the moved punctures'."""
        if not self._duration > 0.0:
            return 0.0
        squares = self._sum_squares + self._shift_squares + (self._drop_term() if self._pending else 0.0)
        return math.sqrt(squares / self._duration)

    @property
    def error(self):
        span = self._high - self._low
        if not self._duration > 0.0 or not span > 0.0:
            return None
        return self.rms_n / span


def inertia_line(mass_scaling, error, rms_n, integrator='explicit', selective_fraction=0.0) -> str:
    """The line every run prints about its mass scaling's estimated error; ``selective_fraction``:
    the mass selective scaling added (Simulation.selective_added_fraction)."""
    if integrator == 'quasi_static':
        return ('quasi-static: no inertia, so no inertia error (its step drops the masses; a mass '
                'scaling only sets the step when time_step_s is null)')
    selective = (f' and {selective_fraction:.2%} more at the smallest elements\' nodes'
                 if selective_fraction > 0.0 else '')
    if mass_scaling <= 1.0 and not selective:
        return 'mass scaling 1: no inertia error added'
    text = 'not estimated (no force range)' if error is None else f'{error:.3f} of the axial force range'
    return (f'mass scaling {mass_scaling:g}{selective}: estimated inertia error {text} (rms {rms_n * 1e3:.1f} '
            f'mN from the scaled inertia and damping and the punctures they move; first order: docs/method.md)')
