"""Each repeat's own draws: the rupture forces and layer depths that make its punctures.

Repeats of one insertion puncture each layer at their own force and depth (the spread
``shared_punctures`` measures). Scored against one nominal simulation, a repeat whose layer gave
way 0.5 mm deeper than the mean charges the model for a shift no parameter of the mean scene can
remove; on the three-layer phantom those shift residuals are most of the objective, and they pull
the shared rupture forces and boundaries toward the repeats' median puncture. Simulated with its
own draws, each repeat is charged only for what the shared keys get wrong: the rupture forces come
to the repeats' mean and the draws' spread is read (docs/performance.md, which also shows what
this does not free: moduli a coarse mesh blends).

On data the draws are not known; they are read from the repeat's punctures by simulation
(:func:`match_repeat_draws`). At the calibration's start every repeat is simulated with its
current offsets ({region: (rupture force offset [N], depth offset [m])}, applied by
``engine.scene.variation.moved_regions``), and for each layer it punctured the offsets move by the
miss of its simulated puncture against the measured one:

    rupture force += F_measured - F_simulated,
    depth         += (d_measured - d_simulated) - (F_measured - F_simulated) / s,

``s`` the measured force's slope over the loading that built the peak (a higher rupture force
alone gives way later by its excess over that slope). A few rounds (``MATCH_ROUNDS``); the
offsets are then held through the search, which moves the shared keys (the scene's moduli,
rupture forces and boundaries) under them.

Offsets matched at a start whose mean puncture is off carry that error in their mean; centring
them alone would put every repeat's puncture off by it again (on the three-layer phantom, the
truth's own draws centred on the nominal values fit 5x worse: 0.00095 against 0.00018). So where
a region's rupture force or boundary is a fitted key, the mean moves into the key's starting
value (:func:`absorb_means`, within its bounds) and out of the offsets: the same simulations,
and the key's value is the mean repeat's. What no key holds stays in the offsets, and the scene
a calibration writes is the mean repeat (:func:`folded_spec`): each rupture force and boundary
moved by its offsets' mean, and the offsets' standard deviations as the scene's spread
(``engine.scene.variation``), so a simulated study of its seeds shows the spread the repeats
were matched with. A layer is the k-th region
with a membrane (the simulation's own layer numbering); a region whose selector has no depth
(``all``, a tag) takes the force offset only.
"""
from __future__ import annotations

import re

import numpy as np

__all__ = ['MATCH_ROUNDS', 'SLOPE_REACH_M', 'absorb_means', 'folded_spec', 'loading_slope', 'match_repeat_draws',
           'means', 'membrane_regions', 'spreads']

#: rounds of simulating every repeat and moving its offsets by its punctures' misses
MATCH_ROUNDS = 3
#: the loading slope is read over at most this much travel before a peak
SLOPE_REACH_M = 0.001
#: the fitted keys that hold a region's mean draw: its rupture force (0) and its boundary (1)
_DRAWN_KEY = re.compile(r'^regions\[([^\]]+)\]\.(membrane\.rupture_force_n|select\.below_z_m)$')


def membrane_regions(spec: dict) -> list:
    """The indices of the regions with a membrane: the k-th is the simulation's layer k."""
    return [k for k, region in enumerate(spec['regions']) if region['membrane']['criterion'] != 'none']


def loading_slope(travel_m, force_n, puncture) -> float:
    """The measured force's slope [N/m] over the loading before ``puncture`` (at most
    SLOPE_REACH_M of its built travel, the peak sample left out); nan with under three samples."""
    travel, force = np.asarray(travel_m, dtype=float), np.asarray(force_n, dtype=float)
    reach = min(puncture.built_m, SLOPE_REACH_M)
    inside = np.flatnonzero((travel >= puncture.travel_m - reach) & (np.arange(len(travel)) < puncture.index))
    if inside.size < 3 or np.ptp(travel[inside]) <= 0:
        return float('nan')
    return float(np.polyfit(travel[inside], force[inside], 1)[0])


def _moved(offsets: list, evaluation, regions: list, deep: set) -> list:
    """One round's offsets from ``evaluation`` (every repeat simulated with ``offsets``)."""
    from tissue_sim_ros.analysis.compare.shared_punctures import pair_punctures
    out = []
    for own, comparison in zip(offsets, evaluation.comparisons):
        own = dict(own)
        if not comparison.diverged:
            for measured, simulated in pair_punctures(comparison.measured_punctures, comparison.simulated_punctures):
                if not 0 <= measured.layer < len(regions):
                    continue
                region = regions[measured.layer]
                force, depth = own.get(region, (0.0, 0.0))
                missed_force = measured.force_n - simulated.force_n
                slope = loading_slope(comparison.travel_since_contact_m, comparison.measured_n, measured)
                missed_depth = measured.travel_m - simulated.travel_m
                if np.isfinite(slope) and slope > 0:
                    missed_depth -= missed_force / slope
                own[region] = (force + missed_force, depth + (missed_depth if region in deep else 0.0))
        out.append(own)
    return out


def spreads(offsets: list) -> dict:
    """{region: (the rupture force offsets' [N], the depth offsets' [m] sample standard deviation)}
    over the repeats that have the region (0 with one repeat)."""
    regions = sorted({r for own in offsets for r in own})
    values = {r: np.array([own[r] for own in offsets if r in own]) for r in regions}
    return {r: tuple(v.std(axis=0, ddof=1)) if len(v) > 1 else (0.0, 0.0) for r, v in values.items()}


def means(offsets: list) -> dict:
    """{region: (mean rupture force offset [N], mean depth offset [m])} over the repeats that have it."""
    regions = sorted({r for own in offsets for r in own})
    return {r: tuple(np.mean([own[r] for own in offsets if r in own], axis=0)) for r in regions}


def absorb_means(keys, u, spec: dict, offsets: list) -> tuple:
    """(``u`` with each fitted rupture force and ``below_z_m`` boundary moved by its region's mean
    offset, held within its bounds; the offsets less what moved): the same runs (module docstring)."""
    u, offsets = np.array(u, dtype=float), [dict(own) for own in offsets]
    names = [region.get('name') for region in spec['regions']]
    mean = means(offsets)
    for i, key in enumerate(keys):
        match = _DRAWN_KEY.match(key.key)
        if not match:
            continue
        selector, part = match[1], 0 if match[2].startswith('membrane') else 1
        region = int(selector) if selector.isdigit() else names.index(selector) if selector in names else None
        if region not in mean:
            continue
        sign = 1.0 if part == 0 else -1.0             # a deeper offset is a lower plane
        value = key.value(u[i])
        u[i] = float(np.clip(key.unit(value + sign * mean[region][part]), 0.0, 1.0))
        taken = sign * (key.value(u[i]) - value)
        for own in offsets:
            if region in own:
                moved = list(own[region])
                moved[part] -= taken
                own[region] = tuple(moved)
    return u, offsets


def folded_spec(spec: dict, offsets: list) -> dict:
    """The scene keys ``spec`` as the mean repeat of ``offsets``: each region's rupture force and
    boundary moved by its offsets' mean, their standard deviations its spread keys (module docstring)."""
    from tissue_sim_ros.engine.scene.variation import has_depth, moved_regions
    regions = moved_regions(spec['regions'], {r: (float(f), float(d)) for r, (f, d) in means(offsets).items()})
    for r, (force, depth) in spreads(offsets).items():
        regions[r] = {**regions[r], 'membrane': {**regions[r]['membrane'], 'rupture_force_spread_n': float(force)}}
        if has_depth(regions[r]['select']):
            regions[r]['depth_spread_m'] = float(depth)
    return {**spec, 'regions': regions}


def match_repeat_draws(objective, u, rounds: int = MATCH_ROUNDS) -> list:
    """Per trial of ``objective`` (built with ``per_repeat=True``), its offsets matched to its
    punctures at the parameters ``u`` (module docstring); left set on the objective. Each round
    is one evaluation of the calibration's budget; a round that moves nothing ends the matching."""
    from tissue_sim_ros.engine.scene.variation import has_depth
    spec = objective.spec_for(u)
    regions = membrane_regions(spec)
    deep = {k for k in regions if has_depth(spec['regions'][k]['select'])}
    offsets = [dict(own) for own in objective.repeat_offsets]
    for _ in range(rounds):
        objective.set_repeat_offsets(offsets)
        moved = _moved(offsets, objective.evaluate(u), regions, deep)
        if moved == offsets:              # nothing to move (no puncture paired): the next round would repeat it
            return offsets
        offsets = moved
    objective.set_repeat_offsets(offsets)
    return offsets
