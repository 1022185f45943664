"""The project's organ (meshing/organ.py, meshed into config/organ_example.vtu) in
config/organ_example.yaml: on springs and a ligament, settled under gravity, its needle planned
through the tumour's centre."""
import numpy as np
import pytest

from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.system.paths import shared_file

EXAMPLE = shared_file('config/organ_example.yaml')


@pytest.fixture(scope='module')
def organ():
    return Scene.from_file(EXAMPLE)


def test_the_organ_is_settled_on_its_supports_and_stays_there(organ):
    sim = organ.simulation
    settled = sim.displacement.copy()
    assert organ.settled is not None and 0.0005 < np.linalg.norm(settled, axis=1).max() < 0.02
    held = np.flatnonzero((sim.dof_kind == 1).all(axis=1))
    assert len(held) >= 3 and len(sim.support_stiffness) > 100
    # the weight is carried: under its own settled state the tissue does not move on its own
    organ.advance(0.1, *organ.initial_needle_pose)
    assert np.abs(sim.displacement - settled).max() < 1e-3 * np.abs(settled).max() + 1e-7
    organ.reset()


def test_the_planned_needle_reaches_the_tumour_centre(organ):
    tumour = organ.target_positions()[organ.targets.names.index('tumour')]
    position, orientation = organ.initial_needle_pose
    axis = organ.needle.axis
    tip = position + organ.needle.geometry.length_m * axis
    offset = tumour - tip
    lateral = np.linalg.norm(offset - (offset @ axis) * axis)
    travel = organ.spec['needle']['planned_travel_m']
    assert lateral < 0.001 and abs(offset @ axis - travel) < 0.002
    assert organ.start_gap_m == pytest.approx(0.001, abs=1e-6)
    assert abs(axis[2]) < 0.95                                     # an oblique approach


def test_the_real_time_variant_is_the_example_but_for_its_three_values():
    """config/organ_example_realtime.yaml repeats the example (the node takes one scene file): every
    key the same but the viscosity, the threshold and the precision it says it changes."""
    from tissue_sim_ros.engine.scene.scene import read_scene_keys

    def flat(spec, prefix=''):
        if isinstance(spec, dict):
            return {k: v for key, value in spec.items() for k, v in flat(value, f'{prefix}{key}.').items()}
        return {prefix.rstrip('.'): spec}
    example = flat(read_scene_keys(EXAMPLE)[0])
    realtime = flat(read_scene_keys(shared_file('config/organ_example_realtime.yaml'))[0])
    assert example.keys() == realtime.keys()
    changed = {key: (example[key], realtime[key]) for key in example if example[key] != realtime[key]}
    assert changed == {'model.nonlinearity_threshold': (0.02, 0.05), 'model.precision': ('float64', 'float32'),
                       'solver.selective_mass_scaling': (1.0, 3.0)}
