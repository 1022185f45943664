"""The node's targets (ros/targets.py): published every tick, recorded, and in the diagnostics."""

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from support.ros_harness import COARSE, publish_at_stamps, straight_descent  # noqa: E402


def test_targets_published_every_tick_recorded_and_in_diagnostics(harness, tmp_path):
    """A target under the needle: tissue/targets every tick (world frame, finite), pushed down by
    the needle, the same messages in the log; the diagnostics' tip distance, lateral miss and
    distance ahead of the tip satisfy distance^2 = miss^2 + ahead^2 (one tick's figures)."""
    from tissue_sim_ros.engine.scene.scene import Scene
    from tissue_sim_ros.io.mcap import read_log
    scene = Scene.from_file(None, mesh=COARSE, targets=[{'name': 'tumour', 'position_m': [0.002, 0.0, -0.012]}])
    h = harness(scene=scene, **{'recording.directory': str(tmp_path)})
    start = h.scene.needle_pose[0]
    stamps, positions = straight_descent(start, 0.005, 3.0, 100.0, h.now_ns())
    publish_at_stamps(h, stamps, positions)
    values = h.diagnostics_now()
    h.stop_node()
    messages = h.get('targets')
    assert len(messages) == h.node.ticks
    z = np.array([m.poses[0].position.z for _, m in messages])
    assert all(m.header.frame_id == 'world' and len(m.poses) == 1 for _, m in messages)
    assert np.isfinite(z).all() and z[0] == pytest.approx(-0.012, abs=1e-12)
    assert z[-1] < -0.012 - 1e-4                      # carried down by the needle's push
    status = values['tissue_sim: targets'][2]
    assert status['names'] == 'tumour'
    distance, miss, ahead = (float(status[f'tumour/{k}']) for k in ('tip_distance_m', 'lateral_miss_m',
                                                                     'ahead_of_tip_m'))
    assert distance ** 2 == pytest.approx(miss ** 2 + ahead ** 2, rel=1e-4)     # values in 6 digits
    assert 0 < ahead < 0.02 and miss == pytest.approx(0.002, abs=5e-4)
    logged = [m for m in read_log(h.node.recording_path, topics=['/tissue/targets'])]
    assert len(logged) == len(messages)
