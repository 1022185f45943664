"""A straight insertion without ROS (analysis/insertion.py): the CSV's target columns say where each
target is, how far it moved and how far the tip is."""

import csv

import numpy as np
import pytest

from tissue_sim_ros.analysis.insertion import run_insertion, target_columns, write_csv
from tissue_sim_ros.engine.scene.scene import Scene

COARSE = ['mesh.fine_size_m=0.003', 'mesh.divisions=[6,6,5]']
TARGETS = 'targets=[{name: tumour, position_m: [0.002, 0.0, -0.015]}, {name: fiducial, position_m: [0.012, -0.007, -0.031]}]'


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
