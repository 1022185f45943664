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
                    (``below_z_m``, ``above_z_m``, a box's, a sphere's or a half-space's
                    point's z),

a normal distribution truncated where a rupture force would not be positive. A spread of depth
needs a selector with a depth (not ``all`` or a tag: refused in ``build.check_combinations``).
"""
from __future__ import annotations

import copy

import numpy as np

__all__ = ['DEPTH_SELECTORS', 'MIN_RUPTURE_FRACTION', 'drawn_regions', 'has_depth', 'has_spread', 'moved_regions']

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
    offsets, drawn = {}, {}
    for k, region in enumerate(regions):
        force = region['membrane']['rupture_force_spread_n'] * normals[2 * k]
        depth = float(region['depth_spread_m'] * normals[2 * k + 1])
        offsets[k] = (force, depth)
    out = moved_regions(regions, offsets)
    for k, region in enumerate(regions):
        if region['membrane']['rupture_force_spread_n'] > 0:
            drawn[f'regions[{k}].membrane.rupture_force_n'] = out[k]['membrane']['rupture_force_n']
        if region['depth_spread_m'] > 0:
            drawn[f'regions[{k}].depth_offset_m'] = offsets[k][1]
    return out, drawn


#: the selectors a run can move down (``all`` and a tag have no depth)
DEPTH_SELECTORS = ('below_z_m', 'above_z_m', 'box_m', 'sphere_m', 'half_space_m')


def has_depth(select) -> bool:
    """Whether a region's selector has a depth a run can move (DEPTH_SELECTORS)."""
    return isinstance(select, dict) and any(key in select for key in DEPTH_SELECTORS)


def moved_regions(regions, offsets: dict) -> list:
    """The scene's ``regions`` as one run builds them: ``offsets`` {region index: (rupture force
    offset [N], depth offset [m], positive deeper)}, the rupture force held to at least
    MIN_RUPTURE_FRACTION of the nominal one, the selector moved down; a region with no depth to
    move keeps its selector. The same rule for a seeded draw and for a repeat's own offsets."""
    out = []
    for k, region in enumerate(regions):
        force, depth = offsets.get(k, (0.0, 0.0))
        if force or (depth and has_depth(region['select'])):
            region = copy.deepcopy(region)
            nominal = region['membrane']['rupture_force_n']
            if force:
                region['membrane']['rupture_force_n'] = max(MIN_RUPTURE_FRACTION * nominal, nominal + force)
            if depth and has_depth(region['select']):
                region['select'] = _moved_down(region['select'], depth)
        out.append(region)
    return out


def _moved_down(select, offset: float):
    """A selector moved down (-z) by ``offset`` metres."""
    if 'below_z_m' in select:
        return {'below_z_m': select['below_z_m'] - offset}
    if 'above_z_m' in select:
        return {'above_z_m': select['above_z_m'] - offset}
    if 'box_m' in select:
        return {'box_m': [[c[0], c[1], c[2] - offset] for c in select['box_m']]}
    if 'half_space_m' in select:                 # its plane through a point moved down
        x, y, z, nx, ny, nz = select['half_space_m']
        return {'half_space_m': [x, y, z - offset, nx, ny, nz]}
    x, y, z, radius = select['sphere_m']
    return {'sphere_m': [x, y, z - offset, radius]}
