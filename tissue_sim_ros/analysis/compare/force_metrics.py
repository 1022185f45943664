"""How far a simulated force curve is from a measured one: curve errors, event errors, per phase.

Both curves are sampled at the same points (the caller aligns and resamples them first). Errors
are simulated minus measured. The normaliser of the NRMSE is the measured force range (max - min)
over the samples compared, unless one is given; it is returned as ``normaliser_n`` so a report can
state it. Per phase, every phase uses the whole trial's normaliser, so that a phase with a small
range (the hold, the near-constant pull of the retraction) is not inflated and the phases'
NRMSEs add up like their RMSEs. R² is the coefficient of determination of the simulation as a
prediction of the measurement: 1 - sum (sim - meas)² / sum (meas - mean meas)² (1 for a perfect
match, 0 for the measured mean, negative when worse than it; NaN for a constant measurement).
Pairs where either side is NaN are left out and counted.
"""
from __future__ import annotations

import numpy as np

from tissue_sim_ros.analysis.compare.force_events import PHASES, Puncture

__all__ = ['curve_errors', 'event_errors', 'peak_force', 'per_phase_errors', 'retraction_minimum']


def curve_errors(measured, simulated, *, normaliser: float | None = None) -> dict:
    """Errors of ``simulated`` against ``measured`` (arrays of one shape), as plain numbers:
    ``rmse_n``, ``nrmse``, ``normaliser_n``, ``r2``, ``bias_n`` (mean error),
    ``max_abs_error_n`` and ``max_abs_error_index`` (flat index into the arrays; -1 when no pair
    is compared), ``count`` (pairs compared) and ``ignored`` (pairs with a NaN)."""
    measured_values = np.asarray(measured, dtype=float)
    simulated_values = np.asarray(simulated, dtype=float)
    if measured_values.shape != simulated_values.shape:
        raise ValueError(f'measured has shape {measured_values.shape} and simulated '
                         f'{simulated_values.shape}; expected the same shape (resample first)')
    if normaliser is not None and not (np.isfinite(normaliser) and normaliser > 0):
        raise ValueError(f'normaliser = {normaliser!r}; expected a finite force > 0 N')
    measured_flat, simulated_flat = measured_values.ravel(), simulated_values.ravel()
    compared = np.flatnonzero(np.isfinite(measured_flat) & np.isfinite(simulated_flat))
    result = {'rmse_n': np.nan, 'nrmse': np.nan, 'normaliser_n': np.nan, 'r2': np.nan,
              'bias_n': np.nan, 'max_abs_error_n': np.nan, 'max_abs_error_index': -1,
              'count': int(compared.size), 'ignored': int(measured_flat.size - compared.size)}
    if compared.size == 0:
        if normaliser is not None:
            result['normaliser_n'] = float(normaliser)
        return result
    reference, error = measured_flat[compared], simulated_flat[compared] - measured_flat[compared]
    rmse = float(np.sqrt(np.mean(error ** 2)))
    scale = float(np.ptp(reference)) if normaliser is None else float(normaliser)
    spread = float(np.sum((reference - reference.mean()) ** 2))
    worst = int(np.argmax(np.abs(error)))
    result.update(rmse_n=rmse, nrmse=rmse / scale if scale > 0 else np.nan, normaliser_n=scale,
                  r2=1.0 - float(np.sum(error ** 2)) / spread if spread > 0 else np.nan,
                  bias_n=float(error.mean()), max_abs_error_n=float(abs(error[worst])),
                  max_abs_error_index=int(compared[worst]))
    return result


def per_phase_errors(measured, simulated, phases, *, normaliser: float | None = None) -> dict:
    """``{phase: curve_errors(...)}`` over each phase present in ``phases`` (one label per
    sample), in the order of :data:`PHASES` then any other label, every phase normalised by the
    whole trial's normaliser (``normaliser``, else the measured range over all compared
    samples)."""
    labels = np.asarray(phases)
    measured_values = np.asarray(measured, dtype=float)
    if labels.shape != measured_values.shape:
        raise ValueError(f'phases has shape {labels.shape}; expected {measured_values.shape} '
                         f'(one label per sample)')
    whole = curve_errors(measured_values, simulated, normaliser=normaliser)
    trial_normaliser = whole['normaliser_n'] if whole['normaliser_n'] > 0 else None
    simulated_values = np.asarray(simulated, dtype=float)
    present = [phase for phase in PHASES if np.any(labels == phase)]
    present += sorted(set(labels.ravel().tolist()) - set(PHASES))
    return {phase: curve_errors(measured_values[labels == phase], simulated_values[labels == phase],
                                normaliser=trial_normaliser)
            for phase in present}


def peak_force(force_n, mask=None) -> float:
    """The largest finite force [N] over ``mask`` (a boolean array; None: every sample), NaN
    when there is none."""
    force = np.asarray(force_n, dtype=float)
    selected = force if mask is None else force[np.asarray(mask, dtype=bool)]
    selected = selected[np.isfinite(selected)]
    return float(selected.max()) if selected.size else np.nan


def retraction_minimum(force_n, phases) -> float:
    """The smallest finite force [N] while retracting (``phases == 'retraction'``): the strongest
    pull of the tissue on the needle on its way out; NaN without a retraction."""
    force = np.asarray(force_n, dtype=float)
    return -peak_force(-force, np.asarray(phases) == 'retraction')


def event_errors(measured_punctures: list[Puncture], simulated_punctures: list[Puncture], *,
                 measured_force_n=None, measured_phases=None, simulated_force_n=None,
                 simulated_phases=None, pairs=None) -> dict:
    """Event errors, simulated minus measured (NaN where either side lacks the event):
    ``first_puncture_travel_error_m`` and ``first_puncture_force_error_n`` (both sides' travel
    must share an origin, e.g. travel since contact), ``measured_puncture_count``,
    ``simulated_puncture_count``; with the forces, ``peak_force_error_n`` (peak outside the
    retraction when phases are given, else over all samples); with forces and phases,
    ``retraction_minimum_error_n``. ``pairs``: (measured, simulated) punctures that are the same
    layer's (default: the first of each); the first measured puncture's pair gives the first
    puncture's errors, and ``puncture_errors`` lists every pair's (``layer``, ``travel_error_m``,
    ``force_error_n``)."""
    if pairs is None:
        pairs = [(measured_punctures[0], simulated_punctures[0])] if measured_punctures and simulated_punctures \
            else []
    first_measured = measured_punctures[0] if measured_punctures else None
    first_simulated = next((s for m, s in pairs if m is first_measured), None)
    both = first_measured is not None and first_simulated is not None
    result = {
        'measured_puncture_count': len(measured_punctures),
        'simulated_puncture_count': len(simulated_punctures),
        'first_puncture_travel_error_m':
            first_simulated.travel_m - first_measured.travel_m if both else np.nan,
        'first_puncture_force_error_n':
            first_simulated.force_n - first_measured.force_n if both else np.nan,
        'peak_force_error_n': np.nan, 'retraction_minimum_error_n': np.nan,
        'puncture_errors': [{'layer': m.layer, 'travel_error_m': s.travel_m - m.travel_m,
                             'force_error_n': s.force_n - m.force_n} for m, s in pairs]}
    if measured_force_n is not None and simulated_force_n is not None:
        result['peak_force_error_n'] = (
            peak_force(simulated_force_n, _outside_retraction(simulated_phases))
            - peak_force(measured_force_n, _outside_retraction(measured_phases)))
        if measured_phases is not None and simulated_phases is not None:
            result['retraction_minimum_error_n'] = (
                retraction_minimum(simulated_force_n, simulated_phases)
                - retraction_minimum(measured_force_n, measured_phases))
    return {key: float(value) if isinstance(value, float) else value
            for key, value in result.items()}


def _outside_retraction(phases):
    return None if phases is None else np.asarray(phases) != 'retraction'
