"""TF in (ros/tf_in.py): the needle's pose from a robot's TF, and poses in other frames brought into
the tissue frame.

Truths: transforms composed by hand with scipy's Rotation (the node's TF code is not used for them);
an independent TF broadcaster process moving tool0 at 1 kHz (support/ros_graph.py): every pose the
engine went to is that motion's, and the node's engine trace replayed gives its wrenches.
"""

import os
import subprocess
import sys
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from support.ros_graph import (
    BROADCASTER,
    DOWN,
    NS,
    OFFSET_M,
    REGISTRATION,
    node_log,
    replay_wrenches,
    truth_times,
)
from tissue_sim_ros.ros.tf_in import TfInput, TransformUnavailable


def matrix(transform):
    """The 4x4 homogeneous matrix of a transform, by scipy."""
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(transform[1]).as_matrix()
    m[:3, 3] = transform[0]
    return m


def test_tf_input_follows_the_tool_frame_and_brings_other_frames_into_the_tissue():
    """The needle base 150 mm along tool0, the tissue registered 0.4 m away and rotated: the pose
    from TF equals the one composed by hand; a pose in base_link comes into the tissue frame."""
    registration = (
        np.array([0.4, 0.1, -0.05]),
        Rotation.from_euler('zyx', [30, 10, -5], degrees=True).as_quat(),
    )
    offset = (np.array([0.0, 0.0, 0.15]), np.array([0.0, 0.0, 0.0, 1.0]))
    tf = TfInput('tissue', tf_frame='tool0', offset=offset, own_frames={'needle'})
    assert isinstance(
        tf.receive([('base_link', 'tool0', NS, (0.1, 0, 0.5), (1, 0, 0, 0))]), TransformUnavailable
    )
    assert tf.receive([('base_link', 'tissue', 0, *registration)], static=True) is not None
    tool = (np.array([0.42, 0.05, 0.3]), Rotation.from_euler('x', 170, degrees=True).as_quat())
    position, orientation, frame, stamp = tf.receive(
        [('base_link', 'tool0', 2 * NS, *tool), ('tissue', 'needle', 2 * NS, (9, 9, 9), (0, 0, 0, 1))]
    )
    expected = np.linalg.inv(matrix(registration)) @ matrix(tool) @ matrix(offset)
    assert frame == 'tissue' and stamp == 2 * NS
    np.testing.assert_allclose(position, expected[:3, 3], atol=1e-12)
    np.testing.assert_allclose(Rotation.from_quat(orientation).as_matrix(), expected[:3, :3], atol=1e-12)
    assert 'needle' not in tf.buffer.frames()  # the node's own frame is skipped
    assert tf.receive([('base_link', 'tool0', 2 * NS, *tool)]) is None  # not newer: nothing
    p, q, frame, _ = tf.to_tissue(tool[0], tool[1], 'base_link', 2 * NS)
    back = np.linalg.inv(matrix(registration)) @ matrix(tool)
    np.testing.assert_allclose(p, back[:3, 3], atol=1e-12)
    # a stamp a little after the newest transform (within input.tf_timeout_s) uses it; later: refused
    tf.to_tissue(tool[0], tool[1], 'tool0', 2 * NS + 50_000_000)
    with pytest.raises(TransformUnavailable, match='tf_timeout_s'):
        tf.to_tissue(tool[0], tool[1], 'tool0', 3 * NS)


def test_tf_input_gives_the_wrench_of_the_same_motion_in_the_tissue_frame(graph, tmp_path):
    speed, seconds = 0.005, 1.2                  # from 1 mm above the surface to 5 mm past it
    g = graph(**{'recording.directory': str(tmp_path), 'input.source': 'tf', 'input.tf_frame': 'tool0',
                 'input.tf_offset_position_m': [0.0, 0.0, OFFSET_M], 'registration.needle_at_first_pose': True,
                 'registration.parent_frame_id': 'base_link', 'registration.tissue_position_m': REGISTRATION[0],
                 'registration.tissue_orientation_xyzw': REGISTRATION[1]})
    start = g.scene.needle_pose[0] - [0.0, 0.0, g.scene.start_gap_m - 0.001]
    robot = subprocess.run(
        [
            sys.executable,
            '-c',
            BROADCASTER,
            repr(start.tolist()),
            str(speed),
            str(seconds),
            str(OFFSET_M),
            repr(REGISTRATION),
        ],
        capture_output=True,
        text=True,
        timeout=60,
        env=dict(os.environ),
    )
    assert robot.returncode == 0, robot.stderr
    t0 = int(robot.stdout.split()[0])
    time.sleep(0.3)
    values = g.node.diagnostics_statuses(time.time_ns())
    g.node.close()
    log = node_log(g.node.recording_path)
    # every wrench the node sent is in the log; its frame is on TF, under the registered tissue
    statics = {t.child_frame_id: t for msg in log['tf_static'] for t in msg.transforms}
    assert (
        statics['world'].header.frame_id == 'base_link' and statics['needle_tip'].header.frame_id == 'needle'
    )
    assert statics['needle_tip'].transform.translation.z == pytest.approx(g.scene.needle.geometry.length_m)
    ours = [t for msg in log['tf'] for t in msg.transforms if t.child_frame_id == 'needle']
    robot_tf = [t for msg in log['tf'] for t in msg.transforms if t.child_frame_id == 'tool0']
    assert len(ours) == len(log['wrench']) and all(t.header.frame_id == 'world' for t in ours)
    assert len(robot_tf) >= 0.9 * seconds * 1000  # the robot's 1 kHz TF, recorded as received
    # the truth: the needle base straight down at `speed` from `start`, in the tissue frame; every
    # pose the engine went to (the trace) is that motion at the advance's clock time, or, where the
    # clock was outside the transforms received (the input holds, never extrapolates), at one of
    # the broadcaster's 1 ms stamps
    rows = np.concatenate([t.rows for t in log['trace']])
    clocks = np.concatenate([t.clock_ns() for t in log['trace']])
    moving = (rows[:, 0] == 0) & ~np.isnan(rows[:, 3])
    assert moving.sum() > 40
    when = truth_times(rows[moving, 5], clocks[moving], start[2], speed, t0, seconds)
    expected = start + np.outer(speed * when, [0.0, 0.0, -1.0])
    np.testing.assert_allclose(rows[moving, 3:6], expected, rtol=0, atol=1e-9)
    angle = np.array(
        [(Rotation.from_quat(q) * Rotation.from_quat(DOWN).inv()).magnitude() for q in rows[moving, 6:10]]
    )
    assert angle.max() < 1e-9
    # the wrench is the engine's for that motion: the trace run through a fresh scene gives the
    # node's wrenches bit for bit. (The hand-made poses are not run in its place: they may differ
    # from the node's by up to 1e-9 m, and two runs that far apart need not give the same wrench
    # to 1e-9 N through the first contact.)
    recorded = np.array([[w.wrench.force.x, w.wrench.force.y, w.wrench.force.z, w.wrench.torque.x,
                          w.wrench.torque.y, w.wrench.torque.z] for w in log['wrench']])
    own, before = replay_wrenches(log['trace'], g.node.engine.threads)
    np.testing.assert_array_equal(own, recorded)
    assert np.abs(recorded[:before, 2]).max() > 0.5, 'the needle should have loaded the tissue before the puncture'
    statuses = {name: values for name, _, _, values in values}
    inputs = statuses['tissue_sim: input']
    print(f"\nTF input: {inputs['poses_received']} poses from TF, latency p50 {inputs['latency_ms_p50']} ms, "
          f"p99 {inputs['latency_ms_p99']} ms")
    assert inputs['source'] == 'tf: tool0 in world'
