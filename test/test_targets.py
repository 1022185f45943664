"""Targets carried by the tissue (engine/scene/targets.py): exact under an affine displacement, the tip
distance and lateral miss against their definitions, refusals by name, and insert's columns."""
import csv

import numpy as np
import pytest

from tissue_sim_ros.analysis.insertion import run_insertion, target_columns, write_csv
from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.errors import SceneError

COARSE = ['mesh.fine_size_m=0.003', 'mesh.divisions=[6,6,5]']
TARGETS = 'targets=[{name: tumour, position_m: [0.002, 0.0, -0.015]}, {name: fiducial, position_m: [0.012, -0.007, -0.031]}]'


@pytest.fixture(scope='module')
def scene():
    return Scene.from_file(None, sets=COARSE + [TARGETS])


def test_targets_follow_an_affine_displacement_exactly(scene):
    """u = (F - I) X at every node: linear interpolation reproduces it, so each target sits at F X."""
    rng = np.random.default_rng(2)
    gradient = 0.05 * rng.normal(size=(3, 3))
    shift = rng.normal(scale=1e-3, size=3)
    x = scene.mesh.rest_positions
    displacement = x @ gradient.T + shift
    positions = scene.targets.positions(displacement)
    expected = scene.targets.rest + scene.targets.rest @ gradient.T + shift
    assert scene.targets.names == ['tumour', 'fiducial']
    assert np.abs(positions - expected).max() < 1e-14
    np.testing.assert_array_equal(scene.target_positions(), scene.targets.rest)    # at rest


def test_tip_distance_and_lateral_miss(scene):
    tip, axis = scene.needle.tip, scene.needle.axis
    distance, miss, ahead = scene.targets_relative_to_needle()
    offset = scene.targets.rest - tip
    assert distance == pytest.approx(np.linalg.norm(offset, axis=1), abs=1e-15)
    assert miss == pytest.approx(np.linalg.norm(np.cross(offset, axis), axis=1), abs=1e-15)
    assert ahead == pytest.approx(offset @ axis, abs=1e-15)
    assert np.all(ahead > 0)          # both below the tip, which points into the tissue


@pytest.mark.parametrize('targets, words', [
    ('[{name: t, position_m: [0.0, 0.0, 0.05]}]', ['targets[0].position_m', 'outside the tissue mesh']),
    ('[{name: t, position_m: [0.0, 0.0, -0.01]}, {name: t, position_m: [0.0, 0.0, -0.02]}]',
     ['targets[1].name', 'another target']),
    ('[{name: t}]', ['targets[0].position_m', 'required']),
    ('[{position_m: [0.0, 0.0, -0.01]}]', ['targets[0].name']),
])
def test_bad_targets_refused_by_name(targets, words):
    with pytest.raises(SceneError) as caught:
        Scene.from_file(None, sets=COARSE + [f'targets={targets}'])
    for word in words:
        assert word in str(caught.value)


def test_insert_reports_each_target(tmp_path):
    """The needle pushes the tissue down before the capsule gives way: the target under it is
    carried along the axis, and the CSV's columns say where it is, how far it moved, how far the
    tip is."""
    scene = Scene.from_file(None, sets=COARSE + [TARGETS, 'needle.start_gap_m=0.001'])
    result = run_insertion(scene, 0.005, 0.008, retract=False)
    tumour = result.target_positions[:, 0]
    assert tumour[-1, 2] < scene.targets.rest[0, 2] - 1e-4            # pushed down over 0.1 mm
    write_csv(result, tmp_path / 'insertion.csv')
    rows = list(csv.DictReader((tmp_path / 'insertion.csv').open()))
    assert set(target_columns(['tumour', 'fiducial'])) <= set(rows[0])
    last = rows[-1]
    position = np.array([float(last[f'target/tumour/{c}']) for c in ('x_m', 'y_m', 'z_m')])
    assert position == pytest.approx(tumour[-1], rel=1e-6)          # the CSV's 7 digits
    assert float(last['target/tumour/displacement_m']) == pytest.approx(
        np.linalg.norm(tumour[-1] - scene.targets.rest[0]), rel=1e-5)
    assert float(last['target/tumour/tip_distance_m']) == pytest.approx(
        np.linalg.norm(tumour[-1] - scene.needle.tip), rel=1e-5)
