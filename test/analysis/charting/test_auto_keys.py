"""``model: auto`` and ``solver.mass_scaling: auto`` (analysis/charting/auto_keys.py): refused by the
engine, naming the key it cannot choose, and resolved above it into the concrete scene a study
reloads."""

import pytest
import yaml

from tissue_sim_ros.engine.scene.scene import Scene, read_scene_keys
from tissue_sim_ros.errors import SceneError


def test_an_auto_scene_is_refused_by_the_engine_and_resolved_above_it(tmp_path, monkeypatch):
    """The engine names the key it cannot choose; the analysis layer chooses it (here a stand-in
    rule) and writes the concrete scene a study reloads in its workers."""
    from tissue_sim_ros.analysis.charting import auto_keys, mass_scaling_rule
    path = tmp_path / 'auto.yaml'
    path.write_text(yaml.safe_dump({'solver': {'mass_scaling': 'auto'}, 'mesh': {'fine_size_m': 0.004,
                                                                                'divisions': [5, 5, 4]}}))
    with pytest.raises(SceneError, match="solver.mass_scaling = 'auto': chosen by measuring"):
        Scene.from_file(path)
    monkeypatch.setattr(mass_scaling_rule, 'auto_mass_scaling', lambda spec, base_dir, quiet=False: (37.0, {'rule': 1}))
    scene = auto_keys.load_scene(path)
    assert scene.simulation.mass_scaling == 37.0 and scene.auto_choices == {'solver.mass_scaling': {'rule': 1}}
    concrete, sets = auto_keys.concrete_scene_file(path, [], tmp_path / 'study')
    assert sets == [] and read_scene_keys(concrete)[0]['solver']['mass_scaling'] == 37.0
    plain = tmp_path / 'plain.yaml'
    plain.write_text('solver: {mass_scaling: 100}\n')
    assert auto_keys.concrete_scene_file(plain, ['model.geometric=false'], tmp_path / 'x') == (plain, ['model.geometric=false'])
