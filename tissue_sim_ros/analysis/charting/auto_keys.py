"""``model: auto`` and ``solver.mass_scaling: auto``: chosen by measuring, before a scene is built.

The engine builds scenes from concrete keys only. Two keys ask for a choice it cannot make
itself, because the choice runs studies of the scene:

- ``solver.mass_scaling: auto``: the largest mass scaling within ``solver.inertia_error_bound``
  (:mod:`.mass_scaling_rule`, probes of the scene's insertion);
- ``model: auto``: the cheapest model, mesh, mass scaling and integrator within
  ``model.auto_tolerance`` that keeps real time (:mod:`.recommend`, the quick chart).

:func:`resolve_auto_keys` turns them into concrete keys (the mass scaling first, so that the
recommendation's chart runs a concrete scene); both results are cached per scene and machine.
Every command that loads a user's scene goes through :func:`load_scene`; the node gets
:func:`resolve_auto_keys` from its console script (``tissue_sim_ros.cli.node_script``).
"""
from __future__ import annotations

import json
from pathlib import Path

from tissue_sim_ros.engine.scene.checks import apply_schema
from tissue_sim_ros.engine.scene.keys import set_key
from tissue_sim_ros.engine.scene.scene import Scene, auto_keys, read_scene_keys, scene_yaml
from tissue_sim_ros.engine.scene.schema import SCHEMA

__all__ = ['concrete_scene_file', 'load_scene', 'resolve_auto_keys']


def resolve_auto_keys(spec: dict, base_dir='.', *, quiet=False) -> tuple[dict, dict]:
    """(checked scene keys with the auto keys chosen, {key: how it was chosen}) of checked scene
    keys ``spec``; unchanged when it has none."""
    from tissue_sim_ros.analysis.charting.mass_scaling_rule import auto_mass_scaling
    from tissue_sim_ros.analysis.charting.recommend import auto_spec
    choices = {}
    if spec['solver']['mass_scaling'] == 'auto':
        chosen, record = auto_mass_scaling(spec, base_dir, quiet=quiet)
        spec = apply_schema('', set_key(spec, 'solver.mass_scaling', chosen), SCHEMA)
        choices['solver.mass_scaling'] = record
    if spec['model']['auto']:
        choices['model.auto'] = {'written': json.loads(json.dumps(spec))}
        spec = apply_schema('', auto_spec(spec, base_dir, quiet=quiet), SCHEMA)
    return spec, choices


def load_scene(path=None, sets=(), values=None, **sections) -> Scene:
    """``Scene.from_file`` with the auto keys resolved: how every command loads a user's scene."""
    return Scene.from_file(path, sets, values, resolve_auto=resolve_auto_keys, **sections)


def concrete_scene_file(path, sets, out) -> tuple[str | None, list]:
    """(scene file, sets) for a study that reloads its scene in every worker: the same when the
    scene has no auto key, else the resolved scene written to ``out/scene.yaml`` (complete, mesh
    files absolute) with no sets left to apply."""
    spec, _, _ = read_scene_keys(path, sets)
    if not auto_keys(spec):
        return path, list(sets)
    resolved = load_scene(path, sets)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    concrete = out / 'scene.yaml'
    concrete.write_text(scene_yaml(resolved.spec, resolved.base_dir,
                                   [f"{path or 'the packaged scene'} with its auto keys chosen: "
                                    f"{', '.join(sorted(resolved.auto_choices))}"]))
    return str(concrete), []
