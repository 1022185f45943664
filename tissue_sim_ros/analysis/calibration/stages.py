"""The calibration's stages, layer by layer: which samples each fitted key acts on.

A layered curve is a sequence: layer 0 loads from contact to its puncture, the tip then cuts
through it until it meets layer 1, which loads to its own puncture, and so on; after the last
puncture the force is the cutting and the shaft's friction; the pause relaxes; the retraction
pulls with the friction of the layer the tip is in, a plateau with a step where it leaves one.
Each key acts on one part of that sequence, so the staged start fits it there, in order:

- every sample of a trial gets a label from the data's own punctures (those its repeats share,
  :func:`sample_labels`): ``segment k`` for the insertion samples between the (k-1)-th puncture
  (or contact) and the k-th (``segment K`` after the last of K), ``hold`` at the deepest travel,
  ``retraction j`` while retracting with the tip in layer j (deeper than puncture j - 1, not
  deeper than puncture j: the boundary it crossed going in), ``approach`` before contact;
- a key's layer is its region's place among the regions with a membrane, in the scene's order
  (:func:`key_layer`: ``regions[2]`` of a scene whose regions 0 and 2 have membranes is layer 1;
  a region without one belongs to the layer before it); model keys have none;
- its kind (:data:`~tissue_sim_ros.analysis.calibration.parameters.PHASE_RULES`): a modulus or law
  coefficient ``loading``, a membrane key or a boundary (``select``) ``puncture``, cutting and
  insertion friction ``inserted``, retraction friction ``retraction``, relaxation ``hold``;
- the stages (:func:`plan_stages`), in this order, each with the keys of its kind and layer:
  ``loading`` (model keys, on every segment before a puncture), then for each layer k
  ``layer k``: its loading and puncture keys together (a layer's modulus, boundary and rupture
  force decide together where its loading starts, how it rises and where it ends) on segment k
  and the k-th puncture's force and depth in every trial that has it (on data without a
  puncture, with the cutting and friction keys: they act on the same samples); ``after puncture
  k`` (segment k + 1); then ``retraction`` (each retraction key on the retraction samples with the tip
  in its layer) and ``pause`` (the hold).

A stage with no key, or without samples, is skipped. Stages that reach only the first segments
run their simulations only that far (the objective's horizons).
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

__all__ = ['Stage', 'key_layer', 'plan_stages', 'sample_labels']


@dataclass(frozen=True)
class Stage:
    """One stage of the staged start: its ``name``, the ``kind`` of its keys, the ``layer`` (None:
    every layer), the sample ``labels`` its residuals come from, the layers whose ``events``
    (puncture force and depth) it fits, and its keys (``free``: indices into the fitted keys)."""

    name: str
    kind: str
    layer: int | None
    labels: tuple = ()
    events: tuple = ()
    free: tuple = ()

    @property
    def key(self) -> str:
        """The stage's scope as text (a cache and horizon key)."""
        return f'stage:{self.labels}:{self.events}'


def key_layer(key: str, regions) -> int | None:
    """The layer a key acts in (module docstring), None for a key outside ``regions``."""
    match = re.match(r'^regions\[([^\]]+)\]', key.strip())
    if not match:
        return None
    selector = match.group(1)
    names = [r.get('name', 'tissue') for r in regions]
    index = int(selector) if re.fullmatch(r'-?\d+', selector) else names.index(selector) if selector in names else None
    if index is None or not 0 <= index < len(regions):
        return None
    membranes = [k for k, r in enumerate(regions) if r['membrane']['criterion'] != 'none']
    return max(0, sum(1 for k in membranes if k < index) - (0 if index in membranes else 1))


def sample_labels(travel_m, phases, punctures) -> np.ndarray:
    """Each sample's label (module docstring): ``travel_m`` since contact, ``phases`` compare's
    (approach, loading, inserted, hold, retraction), ``punctures`` the trial's layered punctures
    (each with its ``layer``, in order of depth)."""
    travel = np.asarray(travel_m, dtype=float)
    phases = np.asarray(phases)
    labels = np.full(len(travel), 'approach', dtype='<U16')
    indices = np.arange(len(travel))
    inserting = np.isin(phases, ('loading', 'inserted'))
    passed = np.zeros(len(travel), dtype=int)
    for p in punctures:
        passed += indices > p.index
    labels[inserting] = np.char.add('segment ', passed[inserting].astype(str))
    labels[phases == 'hold'] = 'hold'
    back = phases == 'retraction'
    depths = sorted((p.layer if p.layer >= 0 else k, p.travel_m) for k, p in enumerate(punctures))
    layer_in = np.zeros(len(travel), dtype=int)
    for layer, depth in depths:
        layer_in = np.where(travel > depth, np.maximum(layer_in, layer + 1), layer_in)
    if depths:
        layer_in = np.minimum(layer_in, depths[-1][0])
    labels[back] = np.char.add('retraction ', layer_in[back].astype(str))
    return labels


def plan_stages(keys, regions, n_layers: int) -> list[Stage]:
    """The stages of the staged start for the fitted ``keys`` (FittedKey) of a scene with these
    ``regions`` on data with ``n_layers`` layers (module docstring)."""
    kinds = [k.phase for k in keys]
    layers = [key_layer(k.key, regions) for k in keys]

    def pick(kind, layer):
        return tuple(i for i, (k, l) in enumerate(zip(kinds, layers)) if k == kind and l == layer)
    loading_all = tuple(f'segment {k}' for k in range(max(n_layers, 1)))
    stages = [Stage('loading', 'loading', None, loading_all, (), pick('loading', None))]
    for k in range(max(n_layers, 1)):
        events = (k,) if k < n_layers else ()
        punctures = (pick('puncture', k) + (pick('puncture', None) if k == 0 else ())) if events else ()
        # data without a puncture: cutting and friction act from contact on, on the very samples
        # the modulus acts on, so they are fitted with it (apart, each would take the other's share)
        inserted = pick('inserted', k) + pick('inserted', None) if n_layers == 0 else ()
        stages.append(Stage(f'layer {k}', 'layer', k, (f'segment {k}',), events,
                            pick('loading', k) + punctures + inserted))
        if k < n_layers:
            stages.append(Stage(f'after puncture {k}', 'inserted', k, (f'segment {k + 1}',), (),
                                pick('inserted', k) + (pick('inserted', None) if k == n_layers - 1 else ())))
    retraction = tuple(i for i, kind in enumerate(kinds) if kind == 'retraction')
    stages.append(Stage('retraction', 'retraction', None,
                        tuple(f'retraction {k}' for k in range(max(n_layers, 1))), (), retraction))
    stages.append(Stage('pause', 'hold', None, ('hold',), (), pick('hold', None)))
    placed = {i for stage in stages for i in stage.free}
    left = tuple(i for i in range(len(keys)) if i not in placed)       # a layer the data does not show
    if left:
        stages.append(Stage('the other keys', 'other', None, loading_all + (f'segment {n_layers}',), (), left))
    return [stage for stage in stages if stage.free]
