"""One run's draw of the spread between repeats: each layer's rupture force and depth.

Repeats of one insertion into one sample do not puncture a layer at one force and one depth:
the measured puncture forces and depths spread (a few tenths of a newton, a few millimetres). A
scene states that spread per region, as standard deviations (``regions[].membrane.
rupture_force_spread_n``, ``regions[].depth_spread_m``), and ``variation.seed`` says which run it
is: seed 0 (the default) is the nominal scene, nothing drawn, bit for bit the scene without the
spread keys; seed k >= 1 is the k-th draw, so a simulated study of N repeats runs seeds 1..N
and shows a spread that can be set beside the measured one.

The draw (numpy's PCG64 generator seeded with k, so a draw is the same on every machine): two
standard normal numbers per region, in region order, whether or not the region has a spread (a
region's draw does not change when another region's spread does): z_f and z_d, and

    rupture force = F0 + s_f z_f, held to at least ``MIN_RUPTURE_FRACTION`` F0,
    depth offset  = s_d z_d (positive: deeper), the region's selector moved down by it
                    (``below_z_m``, ``above_z_m``, a box's or a sphere's z),

a normal distribution truncated where a rupture force would not be positive. A spread of depth
needs a selector with a depth (not ``all`` or a tag: refused in ``build.check_combinations``).
"""
from __future__ import annotations

import copy

import numpy as np

__all__ = ['MIN_RUPTURE_FRACTION', 'drawn_regions', 'has_spread']

#: a drawn rupture force is held to at least this fraction of the nominal one
MIN_RUPTURE_FRACTION = 0.1


def has_spread(spec: dict) -> bool:
    """Whether any region of the checked scene keys ``spec`` states a spread."""
    return any(region['membrane']['rupture_force_spread_n'] > 0 or region['depth_spread_m'] > 0
               for region in spec['regions'])


def drawn_regions(spec: dict) -> tuple[list, dict]:
    """(the regions as this run builds them, {key path: drawn value}) for the checked scene keys
    ``spec`` (module docstring). Seed 0 or no spread: the regions as they are, nothing drawn."""
    seed = int(spec['variation']['seed'])
    regions = spec['regions']
    if seed == 0 or not has_spread(spec):
        return regions, {}
    normals = np.random.default_rng(seed).standard_normal(2 * len(regions))
    out, drawn = [], {}
    for k, region in enumerate(regions):
        region = copy.deepcopy(region)
        membrane = region['membrane']
        if membrane['rupture_force_spread_n'] > 0:
            nominal = membrane['rupture_force_n']
            membrane['rupture_force_n'] = max(MIN_RUPTURE_FRACTION * nominal,
                                              nominal + membrane['rupture_force_spread_n'] * normals[2 * k])
            drawn[f'regions[{k}].membrane.rupture_force_n'] = membrane['rupture_force_n']
        if region['depth_spread_m'] > 0:
            offset = float(region['depth_spread_m'] * normals[2 * k + 1])
            region['select'] = _moved_down(region['select'], offset)
            drawn[f'regions[{k}].depth_offset_m'] = offset
        out.append(region)
    return out, drawn


def _moved_down(select, offset: float):
    """A selector moved down (-z) by ``offset`` metres."""
    if 'below_z_m' in select:
        return {'below_z_m': select['below_z_m'] - offset}
    if 'above_z_m' in select:
        return {'above_z_m': select['above_z_m'] - offset}
    if 'box_m' in select:
        return {'box_m': [[c[0], c[1], c[2] - offset] for c in select['box_m']]}
    x, y, z, radius = select['sphere_m']
    return {'sphere_m': [x, y, z - offset, radius]}
