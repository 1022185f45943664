"""The node's degradation ladder: cheaper engine settings when it cannot keep real time, and back.

Each rung keeps the ones above it and adds one change, taken from what the scene allows and
from settings that change at run time without compiling anything (a new element-pass variant
would compile for about 20 s in the middle of a run):

1. non-linearity threshold 0.1, then 0.5 (a non-linear model whose threshold is lower): elements
   whose displacement gradient norm is below it take the linear path (seed section 6). On the
   default scene 0.02 -> 0.1 costs 20 % less, -> 0.5 26 % less per step.
2. mass scaling x4, then x16, the time step x2, then x4: half, then a quarter, of the substeps
   per simulated second (the critical step grows as the square root of the masses).

The error the ladder predicts for a level is measured, not guessed: the axial force of a standard
indentation run at that level against level 0 (:mod:`~tissue_sim_ros.engine.ladder_probe`),
once per scene, cached.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ['Rung', 'DegradationLadder', 'THRESHOLD_RUNGS', 'MASS_RUNGS']

THRESHOLD_RUNGS = (0.1, 0.5)
MASS_RUNGS = (4.0, 16.0)


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

    def __init__(self, scene, thresholds=THRESHOLD_RUNGS, mass_factors=MASS_RUNGS):
        self.scene = scene
        model = scene.model
        base_threshold = model.nonlinearity_threshold
        self.base_mass_scaling = scene.simulation.mass_scaling
        self.rungs = [Rung('as configured', base_threshold, 1.0, 1.0)]
        threshold, factor = base_threshold, 1.0
        if model.geometric or model.physical:
            for value in thresholds:
                if value > threshold:
                    threshold = value
                    self.rungs.append(Rung(f'non-linearity threshold {value:g}', threshold, factor, 1.2))
        for value in mass_factors:
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

    def predicted_error(self, level: int | None = None) -> float | None:
        """The measured relative axial-force error of ``level`` (default: the current one)."""
        level = self.level if level is None else level
        return None if self.predicted_errors is None else self.predicted_errors[level]
