"""Punctures the repeats share: a layer is a drop found at about one depth in most repeats.

One curve's local maxima are not its layers: a surface dimple gives way before the first puncture
(a pre-drop), a peak is rounded or its drop partial, and one repeat's small drop is another's
clear one. Repeats of one condition pass through the same layers, so a layer is what they share.
The rules (:func:`shared_punctures`; depths are travel since contact, one origin for all repeats):

1. Each repeat's drops: :func:`~tissue_sim_ros.analysis.compare.force_events.detect_drops`
   (punctures and pre-drops, each with its own noise threshold).
2. Groups: the punctures of every repeat, sorted by depth; a group ends where the next one is
   more than ``GROUP_GAP_M`` deeper than the last one in it, or belongs to a repeat the group
   already holds (a repeat passes a layer once).
3. For each group, a repeat without a puncture in it: the largest of its drops (a pre-drop, or a
   drop under the fraction a puncture needs, down to the noise threshold) within the group's
   depths widened by ``max(SEARCH_SPREADS x the depth's standard deviation, SEARCH_MARGIN_M)`` is
   its puncture there; with none there, the repeat missed it.
4. Layers: the groups whose punctures, with those found by rule 3, come from more than half the
   repeats; with one repeat, each of its punctures. A small drop near the puncture fraction is a
   puncture in one repeat and just under it in another; the group of one repeat's stray drop, that
   no other repeat has a drop near, is dropped.
5. Each layer: depth and peak force as distributions over the repeats that have it (mean, sample
   standard deviation, range), the mean drop, and how many repeats have it.

Two layers whose depth ranges overlap by more than their spread cannot be told apart this way;
the groups then merge by rule 2 and the report says how many repeats each layer holds.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from tissue_sim_ros.analysis.compare.force_events import PUNCTURE, Puncture, detect_drops

__all__ = ['EVENT_WINDOW_M', 'GROUP_GAP_M', 'Layer', 'SPREAD_DEVIATIONS', 'SharedPunctures', 'pair_punctures',
           'shared_punctures', 'within_spread']

#: a group of punctures ends where the next is this much deeper than its last
GROUP_GAP_M = 0.0015
#: compare's pointwise errors leave out this much travel around each puncture of either curve
EVENT_WINDOW_M = 0.00015
#: a simulated puncture is within the repeats' spread when it is this many standard deviations of
#: their depths from its layer's mean, or within their range (and EVENT_WINDOW_M beyond)
SPREAD_DEVIATIONS = 2.0

#: a repeat missing a layer's puncture is searched within this many standard deviations of its
#: depth, and at least SEARCH_MARGIN_M
SEARCH_SPREADS, SEARCH_MARGIN_M = 3.0, 0.0008


@dataclass(frozen=True)
class Layer:
    """A puncture the repeats share: depth since contact [m] and peak force [N] as distributions
    (mean, sample standard deviation, min and max), the mean drop [N], the repeats that have it
    (``found``, of ``repeats``; ``assisted`` of them found by rule 4)."""

    depth_m: float
    depth_sd_m: float
    depth_range_m: tuple
    force_n: float
    force_sd_n: float
    force_range_n: tuple
    drop_n: float
    found: int
    repeats: int
    assisted: int = 0

    def as_dict(self) -> dict:
        return {'depth_m': self.depth_m, 'depth_sd_m': self.depth_sd_m, 'depth_min_m': self.depth_range_m[0],
                'depth_max_m': self.depth_range_m[1], 'force_n': self.force_n, 'force_sd_n': self.force_sd_n,
                'force_min_n': self.force_range_n[0], 'force_max_n': self.force_range_n[1], 'drop_n': self.drop_n,
                'found': self.found, 'repeats': self.repeats, 'assisted': self.assisted}


@dataclass
class SharedPunctures:
    """The layers (in depth order) and, per repeat, its puncture of each layer (None: missed);
    ``pre_drops`` per repeat: its pre-drops (drops the loading regained at once)."""

    layers: list
    by_repeat: list
    pre_drops: list = field(default_factory=list)

    def punctures_of(self, repeat: int) -> list[Puncture]:
        """The repeat's punctures in depth order (the layers it has)."""
        return [p for p in self.by_repeat[repeat] if p is not None]


def _spread(values) -> tuple[float, float, tuple]:
    values = np.asarray(values, dtype=float)
    sd = float(np.std(values, ddof=1)) if values.size >= 2 else 0.0
    return float(values.mean()), sd, (float(values.min()), float(values.max()))


def _groups(events_by_repeat) -> list[list]:
    """Rule 2: (repeat, puncture) groups."""
    flat = sorted(((p.travel_m, r, p) for r, events in enumerate(events_by_repeat) for p in events
                   if p.kind == PUNCTURE), key=lambda item: item[0])
    groups: list[list] = []
    for depth, repeat, puncture in flat:
        current = groups[-1] if groups else None
        if current is None or depth - current[-1][1].travel_m > GROUP_GAP_M or repeat in {r for r, _ in current}:
            groups.append([(repeat, puncture)])
        else:
            current.append((repeat, puncture))
    return groups


def shared_punctures(travels, forces, *, inserting=None, min_drop_fraction: float = 0.15) -> SharedPunctures:
    """The layers several repeats share (rules in the module docstring). ``travels``: each repeat's
    travel since contact [m], ``forces`` its axial force [N], ``inserting`` its advancing samples
    (None: before its deepest travel)."""
    travels, forces = list(travels), list(forces)
    masks = list(inserting) if inserting is not None else [None] * len(travels)
    if not travels or len(forces) != len(travels) or len(masks) != len(travels):
        raise ValueError(f'travels, forces and inserting hold {len(travels)}, {len(forces)} and {len(masks)} '
                         'repeats; expected one entry each, at least one repeat')
    events = [detect_drops(t, f, inserting=m, min_drop_fraction=min_drop_fraction)
              for t, f, m in zip(travels, forces, masks)]
    weak = [detect_drops(t, f, inserting=m, min_drop_fraction=0.0) for t, f, m in zip(travels, forces, masks)]
    repeats = len(travels)
    needed = repeats // 2 + 1
    layers, by_repeat = [], [[] for _ in range(repeats)]
    for group in _groups(events):
        members = dict(group)
        depth, depth_sd, _ = _spread([p.travel_m for p in members.values()])
        margin = max(SEARCH_SPREADS * depth_sd, SEARCH_MARGIN_M)
        low = min(p.travel_m for p in members.values()) - margin
        high = max(p.travel_m for p in members.values()) + margin
        found_near = {}
        for r in range(repeats):
            if r in members:
                continue
            taken = {p.index for p in by_repeat[r] if p is not None}
            near = [p for p in weak[r] if low <= p.travel_m <= high and p.index not in taken]
            if near:
                found_near[r] = max(near, key=lambda p: p.drop_n)
        if len(group) + len(found_near) < needed:
            continue
        members.update(found_near)
        assisted = len(found_near)
        members = {r: replace(p, layer=len(layers)) for r, p in members.items()}
        for r in range(repeats):
            by_repeat[r].append(members.get(r))
        found = [p for p in members.values()]
        depth, depth_sd, depth_range = _spread([p.travel_m for p in found])
        force, force_sd, force_range = _spread([p.force_n for p in found])
        layers.append(Layer(depth, depth_sd, depth_range, force, force_sd, force_range,
                            float(np.mean([p.drop_n for p in found])), len(found), repeats, assisted))
    pre_drops = [[p for p in repeat_events if p.kind != PUNCTURE
                  and not any(q is not None and q.index == p.index for q in by_repeat[r])]
                 for r, repeat_events in enumerate(events)]
    return SharedPunctures(layers, by_repeat, pre_drops)


def pair_punctures(measured, simulated, max_distance_m: float = float('inf')) -> list[tuple]:
    """(measured, simulated) pairs of punctures: by layer where both know theirs (``layer`` >= 0:
    the k-th layer of the data with the k-th layer the simulation punctured); the others the
    nearest in travel first, each used once, no pair farther apart than ``max_distance_m``, and in
    order (a pair that would cross another is left out). In order of the measured punctures."""
    if measured and simulated and all(p.layer >= 0 for p in measured) and all(p.layer >= 0 for p in simulated):
        by_layer = {p.layer: p for p in reversed(simulated)}
        return [(m, by_layer[m.layer]) for m in measured if m.layer in by_layer]
    candidates = sorted((abs(s.travel_m - m.travel_m), i, j) for i, m in enumerate(measured)
                        for j, s in enumerate(simulated) if abs(s.travel_m - m.travel_m) <= max_distance_m)
    pairs: list[tuple] = []
    for _, i, j in candidates:
        if any(i == a or j == b or (i - a) * (j - b) < 0 for a, b in pairs):
            continue
        pairs.append((i, j))
    return [(measured[i], simulated[j]) for i, j in sorted(pairs)]


def within_spread(measured, simulated, layers) -> bool:
    """Whether ``simulated`` (paired with the repeat's puncture ``measured``) lies within the
    depths of that layer's repeats (``layers``: :class:`Layer` by layer index;
    see SPREAD_DEVIATIONS)."""
    if not layers or not 0 <= measured.layer < len(layers):
        return False
    layer = layers[measured.layer]
    low, high = layer.depth_range_m
    reach = max(SPREAD_DEVIATIONS * layer.depth_sd_m, 0.5 * (high - low)) + EVENT_WINDOW_M
    return abs(simulated.travel_m - layer.depth_m) <= reach
