"""The ``--fit`` keys and bounds a calibration of a proposed layered scene takes (``propose``
writes them into its report and its calibrate command).

Per layer: its modulus within 3x of the proposal's (log); a deeper boundary within three depth
spreads or 2 mm and, on the side the proposal's own simulation says it lies, further by the
travel its loading still starts off the data's (the refinement moves a boundary by that miss a
run and may stop short: its last runs score the other values too); its rupture force within
50 %; its cutting force up to twice (or 0.5 N more); its retraction pull up to twice (or 0.5 N)
and at least ``PULL_MARGIN`` times the data's strongest pull: a layer the tip leaves soon after
the turn (dragging the tissue with it) has a window that holds only the transition and reads
low, yet no one layer pulls harder than the whole retraction does. Then each layer's insertion
friction within 3x (log) and the pause's relaxation (its relaxing part over 0.05 to 0.95, its
time within 5x).
"""
from __future__ import annotations

import math

__all__ = ['PULL_MARGIN', 'fit_suggestions']

#: a layer's retraction pull is fitted up to this times the data's strongest pull at least
PULL_MARGIN = 1.25


def fit_suggestions(spec: dict, n_layers: int, layers, strongest_pull_n: float = math.nan,
                    onset_miss_m=()) -> list[dict]:
    """The ``--fit`` keys (module docstring) around the values of ``spec``, the proposal's scene;
    ``layers`` the data's layers (their ``depth_sd_m``); ``strongest_pull_n`` negative, NaN: none;
    ``onset_miss_m`` per layer the travel where its simulated loading starts less the data's (NaN,
    or missing: unknown)."""
    rows = []

    def add(key, low, high, log=False, acts=''):
        rows.append({'key': key, 'low': float(low), 'high': float(high), 'log': log, 'acts_on': acts,
                     'text': f'{key}={low:.6g}:{high:.6g}' + (':log' if log else '')})
    for k, region in enumerate(spec['regions'][:n_layers]):
        add(f'regions[{k}].young_modulus_pa', region['young_modulus_pa'] / 3, region['young_modulus_pa'] * 3, True,
            f'layer {k} loading')
        if k >= 1:
            z = region['select']['below_z_m']
            margin = max(3 * layers[k].depth_sd_m, 0.002)
            miss = onset_miss_m[k] if k < len(onset_miss_m) and math.isfinite(onset_miss_m[k]) else 0.0
            low, high = z - margin - max(-miss, 0.0), min(z + margin + max(miss, 0.0), -1e-4)
            add(f'regions[{k}].select.below_z_m', low, high, False, f'where layer {k} loading starts, its puncture depth')
        rupture = region['membrane']['rupture_force_n']
        add(f'regions[{k}].membrane.rupture_force_n', 0.5 * rupture, 1.5 * rupture, False, f'puncture {k}')
        cutting = region['cutting_force_n']
        add(f'regions[{k}].cutting_force_n', 0.0, max(2 * cutting, cutting + 0.5), False,
            f'after puncture {k}')
        retraction = region['friction']['retraction_constant_n']
        strongest = PULL_MARGIN * -strongest_pull_n if math.isfinite(strongest_pull_n) else 0.0
        add(f'regions[{k}].friction.retraction_constant_n', 0.0, max(2 * retraction, 0.5, strongest), False,
            f'retraction with the tip in layer {k}')
    for k, region in enumerate(spec['regions'][:n_layers]):
        coulomb = region['friction']['insertion_coulomb_n_per_m']
        if coulomb > 0:
            add(f'regions[{k}].friction.insertion_coulomb_n_per_m', coulomb / 3, coulomb * 3, True,
                f'after puncture {k}')
    if spec['model']['relaxation']:
        term = spec['model']['relaxation'][0]
        add('model.relaxation[0].relative_modulus', 0.05, 0.95, False, 'the pause')
        add('model.relaxation[0].time_constant_s', term['time_constant_s'] / 5, term['time_constant_s'] * 5, True,
            'the pause')
    return rows
