"""The node's degradation ladder: cheaper engine settings when it cannot keep real time, and back.

Each rung keeps the ones above it and adds one change (:data:`STEPS`, in order), taken from what
the scene allows and from settings that change at run time without compiling anything (a new
element-pass variant would compile for about 20 s in the middle of a run):

- a non-linearity threshold (a non-linear model whose threshold is lower): elements whose
  displacement gradient norm is below it take the linear path (seed section 6). On the default
  scene 0.02 -> 0.1 costs 20 % less, -> 0.5 26 % less per step;
- a mass scaling x4, then x16: the time step x2, then x4, half then a quarter of the substeps per
  simulated second (the critical step grows as the square root of the masses). The damping force
  stays the scene's (Simulation.rescale_masses), so at millimetres per second little changes. A
  mass rung whose time step would pass ``MAX_RUNG_TIME_STEP_S`` is not offered: on a coarse test
  box (6 x 6 x 4 cells, 8.9 ms as configured) a 2.6 s descent at 4 mm/s gives the same force
  whatever the clock's offset within a step at 8.9 ms, but at 17.8 ms (x4) and 35.6 ms (x16) the
  capsule breaks at first contact for some offsets, whether the damping is kept or scaled along.
  The default scene's x16 step is 4.9 ms.

The order is by error for what they save, measured with the probe below on the default scene
(each level's error against level 0): threshold 0.1 0.0057, mass x4 0.0061, x16 0.0128 (a
quarter of the substeps for about 1 %), then threshold 0.5 0.119 (most of the law's stiffening
gone). The mass rungs' errors are this small because they keep the damping force: scaled with
the masses, the damping would put them after both thresholds.

The error the ladder predicts for a level is measured, not guessed: the axial force of a standard
indentation run at that level against level 0 (:mod:`~tissue_sim_ros.engine.ladder_probe`),
once per scene, cached.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ['Rung', 'DegradationLadder', 'STEPS', 'MAX_RUNG_TIME_STEP_S', 'RUNG_RULES']

#: the rungs' changes in order: ('threshold', value) or ('mass', factor on the scene's scaling)
STEPS = (('threshold', 0.1), ('mass', 4.0), ('mass', 16.0), ('threshold', 0.5))
#: the longest time step a mass rung may take [s] (module docstring)
MAX_RUNG_TIME_STEP_S = 0.01
#: what a rung changes, for the probe's cache (a change here measures every scene again)
RUNG_RULES = f'{STEPS!r}: the damping force kept, steps up to {MAX_RUNG_TIME_STEP_S} s'


@dataclass(frozen=True)
class Rung:
    """One level of the ladder: its name, the non-linearity threshold, the factor on the scene's
    mass scaling, and the cost per simulated second it is expected to save against the level
    above (a priori; the node measures it when it steps down)."""

    name: str
    threshold: float
    mass_factor: float
    cost_ratio: float


class DegradationLadder:
    """The rungs of a scene (level 0: as configured) and the switch between them.
    ``predicted_errors``: per level, the relative axial-force error against level 0 (None until
    measured, :func:`~tissue_sim_ros.engine.ladder_probe.cached_probe_errors`)."""

    def __init__(self, scene, steps=STEPS, max_time_step_s=MAX_RUNG_TIME_STEP_S):
        self.scene = scene
        model = scene.model
        base_threshold = model.nonlinearity_threshold
        self.base_mass_scaling = scene.simulation.mass_scaling
        base_dt = scene.simulation.dt
        self.rungs = [Rung('as configured', base_threshold, 1.0, 1.0)]
        threshold, factor = base_threshold, 1.0
        for kind, value in steps:
            if kind == 'threshold' and (model.geometric or model.physical) and value > threshold:
                threshold = value
                self.rungs.append(Rung(f'non-linearity threshold {value:g}', threshold, factor, 1.2))
            elif kind == 'mass' and value > factor and base_dt * math.sqrt(value) <= max_time_step_s:
                self.rungs.append(Rung(f'mass scaling x{value:g}, time step x{math.sqrt(value):g}',
                                       threshold, value, math.sqrt(value / factor)))
                factor = value
        self.level = 0
        self.predicted_errors: list[float] | None = None

    @property
    def rung(self) -> Rung:
        return self.rungs[self.level]

    @property
    def bottom(self) -> int:
        return len(self.rungs) - 1

    def set_level(self, level: int) -> None:
        """Switch the scene to the settings of ``level`` (between steps)."""
        if not 0 <= level < len(self.rungs):
            raise ValueError(f'level = {level!r}: expected 0 .. {self.bottom}')
        rung, simulation = self.rungs[level], self.scene.simulation
        self.scene.model.set_nonlinearity_threshold(rung.threshold)
        mass_scaling = self.base_mass_scaling * rung.mass_factor
        if mass_scaling != simulation.mass_scaling:
            simulation.rescale_masses(mass_scaling)
        self.level = level

    def cheapest_within(self, max_error: float) -> int | None:
        """The cheapest (deepest) level whose measured error is at most ``max_error`` (0 when none
        is); None before the errors are measured."""
        errors = self.predicted_errors
        if errors is None or None in errors:
            return None
        return max(k for k, error in enumerate(errors) if error <= max_error or k == 0)

    def predicted_error(self, level: int | None = None) -> float | None:
        """The measured relative axial-force error of ``level`` (default: the current one)."""
        level = self.level if level is None else level
        return None if self.predicted_errors is None else self.predicted_errors[level]
