"""Layered insertion curves drawn from a formula, for testing what the simulator cannot make.

The simulator's membranes rupture at once when their force is reached, so its curves have no
pre-drop (a surface dimple that gives way and is loaded again at once) and no rounded peak (a
layer that yields over a millimetre before it gives). Real multi-layer curves have both, and a
puncture detector must tell them from punctures. This module draws such curves from a formula
whose every event is known (:func:`layered_curve`), sampled like a load cell (uniform rate, white
noise), with the insertion, a pause and the retraction of a stage:

- loading of the outer layer from contact: F = s0 x + c0 x^2, c0 chosen so that F reaches the
  first peak at the first puncture's depth;
- a pre-drop at ``pre_drop_m`` (optional): the loading minus ``pre_drop_n`` exp(-(x - x_p) / w_p),
  w_p = ``PRE_DROP_WIDTH_M``: a drop the same loading regains within a fraction of a millimetre;
- each puncture k at depth d_k and peak P_k: the force falls to (1 - f_k) P_k (a partial drop,
  f_k the drop fraction), the peak rounded by a cosine over ``rounding_m[k]`` of travel centred
  on it (0: a sharp drop at one sample); then the next layer loads linearly from that level to its
  peak; after the last puncture the force rises with the inserted-friction slope;
- a pause of ``hold_s``: the force relaxes as F_end (1 - g (1 - exp(-t / tau)));
- the retraction: the force falls to -R_deep within ``transition_m`` (exponentially) and holds
  there while the tip is below the last boundary (``step_depth_m``), then -R_shallow until the
  tip leaves the surface.

Everything is in SI; depths are travel since contact; the needle meets the surface ``gap_m``
after the stage starts.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ['PRE_DROP_WIDTH_M', 'LayeredCurve', 'layered_curve']

PRE_DROP_WIDTH_M = 0.00015


@dataclass
class LayeredCurve:
    """A drawn curve: time [s], travel from the stage's start [m], axial force [N]; the truth:
    the punctures' depths since contact [m] and peak forces [N], the pre-drop's depth (None)."""

    time_s: np.ndarray
    travel_m: np.ndarray
    force_n: np.ndarray
    puncture_depths_m: list
    puncture_forces_n: list
    pre_drop_m: float | None = None
    gap_m: float = 0.0
    noiseless_n: np.ndarray = field(default=None, repr=False)


def _insertion_force(x, depths, peaks, fractions, rounding, friction_slope, first_slope, pre_drop_m, pre_drop_n):
    """The insertion's noiseless force at depths since contact ``x`` (module docstring)."""
    depths, peaks = np.asarray(depths, float), np.asarray(peaks, float)
    curvature = (peaks[0] - first_slope * depths[0]) / depths[0] ** 2
    force = np.where(x > 0, first_slope * x + curvature * x * x, 0.0)
    if pre_drop_m is not None:
        force = force - np.where(x >= pre_drop_m, pre_drop_n * np.exp(-(x - pre_drop_m) / PRE_DROP_WIDTH_M), 0.0)
    for k, (depth, peak, fraction, width) in enumerate(zip(depths, peaks, fractions, rounding)):
        level = (1.0 - fraction) * peak
        if k + 1 < len(depths):
            after = level + (peaks[k + 1] - level) / (depths[k + 1] - depth) * (x - depth)
        else:
            after = level + friction_slope * (x - depth)
        if width > 0:                 # rounded: the loading bends over and falls within the width
            u = np.clip((x - (depth - 0.5 * width)) / width, 0.0, 1.0)
            blend = 0.5 - 0.5 * np.cos(np.pi * u)
            shaped = (1 - blend) * np.minimum(force, peak) + blend * after
            force = np.where(x <= depth - 0.5 * width, force, np.where(x >= depth + 0.5 * width, after, shaped))
        else:
            force = np.where(x <= depth, force, after)
    return force


def layered_curve(rng, *, depths_m=(0.0135, 0.020), peaks_n=(4.0, 5.0), drop_fractions=(0.5, 0.3),
                  first_slope_n_per_m=150.0, rounding_m=(0.0, 0.0015), friction_n_per_m=40.0,
                  pre_drop_m=0.0094, pre_drop_n=0.5, travel_m=0.025, gap_m=0.002, speed_m_s=0.002,
                  hold_s=5.0, relax_fraction=0.45, relax_time_s=1.5, retraction_deep_n=1.8,
                  retraction_shallow_n=1.3, transition_m=0.002, step_depth_m=None, rate_hz=100.0,
                  noise_n=0.005) -> LayeredCurve:
    """A layered insertion, pause and retraction drawn from the formula of the module docstring:
    punctures at ``depths_m`` (since contact) with peaks ``peaks_n``; ``first_slope_n_per_m`` is the
    outer layer's slope at contact."""
    if len(depths_m) != len(peaks_n) or len(drop_fractions) != len(depths_m) or len(rounding_m) != len(depths_m):
        raise ValueError('depths_m, peaks_n, drop_fractions and rounding_m need one entry per puncture')
    total = gap_m + travel_m
    insert_s = total / speed_m_s
    duration = 2 * insert_s + hold_s
    time = np.arange(0.0, duration, 1.0 / rate_hz)
    travel = np.where(time <= insert_s, speed_m_s * time,
                      np.where(time <= insert_s + hold_s, total, total - speed_m_s * (time - insert_s - hold_s)))
    travel = np.clip(travel, 0.0, total)
    depth = travel - gap_m
    inserting = time <= insert_s
    force = np.zeros_like(time)
    shape = (depths_m, peaks_n, drop_fractions, rounding_m, friction_n_per_m, first_slope_n_per_m, pre_drop_m,
             pre_drop_n)
    force[inserting] = _insertion_force(depth[inserting], *shape)
    end_force = float(_insertion_force(np.array([travel_m]), *shape)[0])
    holding = (time > insert_s) & (time <= insert_s + hold_s)
    force[holding] = end_force * (1 - relax_fraction * (1 - np.exp(-(time[holding] - insert_s) / relax_time_s)))
    relaxed = end_force * (1 - relax_fraction * (1 - np.exp(-hold_s / relax_time_s)))
    back = time > insert_s + hold_s
    out = total - travel[back]                                      # retracted so far
    boundary = depths_m[-2] if step_depth_m is None and len(depths_m) > 1 else (step_depth_m or 0.0)
    plateau = np.where(depth[back] > boundary, -retraction_deep_n, -retraction_shallow_n)
    plateau = np.where(depth[back] > 0, plateau, 0.0)
    force[back] = plateau + (relaxed - plateau) * np.exp(-out / (transition_m / 3.0))
    noisy = force + rng.normal(0.0, noise_n, time.size)
    return LayeredCurve(time, travel, noisy, list(depths_m), list(peaks_n), pre_drop_m, gap_m, force)
