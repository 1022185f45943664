"""A scene: its keys (YAML) -> mesh, regions, model, supports, solver, needles, targets.

- :mod:`.schema`: every scene key with its default, kind, unit and meaning, and their checks;
- :mod:`.keys`: scene values read and set by key path (``regions[0].young_modulus_pa``), the
  ``--set KEY=VALUE`` of the commands;
- :mod:`.variation`: one run's draw of the spread between repeats (rupture forces, layer depths);
- :mod:`.targets`: named points carried by the tissue (a tumour, a fiducial);
- :mod:`.build`: one builder of material, model and simulation from checked keys;
- :mod:`.scene`: :class:`Scene`, the engine's whole-step API.
"""
__all__ = ['build', 'keys', 'scene', 'schema', 'targets', 'variation']
