"""A robot's rosbag2 MCAP recording as a trial (io/trials/mcap_files.py), against the arrays the
log was written from; each bad log against the error it must get."""

import numpy as np
import pytest

from tissue_sim_ros.errors import DataError

T0_NS = 1_700_000_000_123_456_789
WRENCH_TOPIC, POSE_TOPIC = '/ft_sensor/wrench', '/robot/needle_pose'


def travel_at(time_s):
    """2 mm/s for 1.2 s, then hold: piecewise linear with its kink on a 50 Hz pose sample."""
    return 0.002 * np.minimum(time_s, 1.2)


def stamp(ns):
    from builtin_interfaces.msg import Time
    return Time(sec=int(ns) // 1_000_000_000, nanosec=int(ns) % 1_000_000_000)


def write_robot_log(path, *, rotation_xyzw, base_at, force_at, wrench_frame, pose_frame='world',
                    child_frame=None, swap_stamps=(), repeat_stamp=None):
    """Poses at 50 Hz for 2 s, wrenches at 200 Hz from 1.3 ms; the wrench messages of the pairs
    ``swap_stamps`` are logged in the other order (as a driver's messages can arrive), the
    message after ``repeat_stamp`` repeats its stamp. Returns the wrench times [ns] in time order
    with their forces and torques."""
    pytest.importorskip('rclpy')
    from geometry_msgs.msg import PoseStamped, TransformStamped, WrenchStamped
    from rclpy.serialization import serialize_message

    from tissue_sim_ros.io.mcap.writer import McapRecorder
    pose_ns = T0_NS + np.arange(101) * 20_000_000
    wrench_ns = T0_NS + 1_300_000 + np.arange(390) * 5_000_000
    header_ns = wrench_ns.copy()
    for j in swap_stamps:
        header_ns[[j, j + 1]] = header_ns[[j + 1, j]]
    if repeat_stamp is not None:
        header_ns[repeat_stamp + 1] = header_ns[repeat_stamp]
    forces = np.array([force_at((ns - T0_NS) * 1e-9) for ns in header_ns], dtype=np.float64)
    torques = np.random.default_rng(5).normal(0, 1e-3, (len(wrench_ns), 3))
    pose_type = 'PoseStamped' if child_frame is None else 'TransformStamped'
    with McapRecorder(path, metadata={}, background=False) as recorder:
        recorder.add_topic(WRENCH_TOPIC, 'geometry_msgs/msg/WrenchStamped')
        recorder.add_topic(POSE_TOPIC, f'geometry_msgs/msg/{pose_type}')
        events = [(ns, 'pose', k) for k, ns in enumerate(pose_ns)]
        events += [(ns, 'wrench', j) for j, ns in enumerate(wrench_ns)]
        for log_ns, kind, index in sorted(events):
            if kind == 'pose':
                position = base_at((pose_ns[index] - T0_NS) * 1e-9)
                if child_frame is None:
                    msg = PoseStamped()
                    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = position
                    q = msg.pose.orientation
                else:
                    msg = TransformStamped(child_frame_id=child_frame)
                    t = msg.transform.translation
                    t.x, t.y, t.z = position
                    q = msg.transform.rotation
                q.x, q.y, q.z, q.w = rotation_xyzw
                msg.header.frame_id, msg.header.stamp = pose_frame, stamp(pose_ns[index])
                recorder.write(POSE_TOPIC, serialize_message(msg), int(log_ns))
            else:
                msg = WrenchStamped()
                msg.header.frame_id, msg.header.stamp = wrench_frame, stamp(header_ns[index])
                f, tq = msg.wrench.force, msg.wrench.torque
                f.x, f.y, f.z = forces[index]
                tq.x, tq.y, tq.z = torques[index]
                recorder.write(WRENCH_TOPIC, serialize_message(msg), int(log_ns))
    order = np.argsort(header_ns)
    return header_ns[order], forces[order], torques[order]


def axial_truth(time_s):
    return 1500 * travel_at(time_s) + 0.2 * np.sin(7 * time_s)


def downward_log(path, wrench_frame='world', swap_stamps=()):
    """The scene's default needle: turned 180 deg about x (axis world -z), inserting downward
    with a lateral wobble in x; the force on the needle resists along world +z."""
    return write_robot_log(
        path, rotation_xyzw=(1.0, 0.0, 0.0, 0.0),
        base_at=lambda t: (1e-3 * np.sin(5 * t), 0.0, 0.16 - travel_at(t)),
        force_at=lambda t: (0.05 * np.cos(t), -0.03, axial_truth(t)),
        wrench_frame=wrench_frame, swap_stamps=swap_stamps)


def test_mcap_round_trip_world_frame_wrench(tmp_path):
    from tissue_sim_ros.io.trials.mcap_files import read_mcap_trial
    path = tmp_path / 'robot.mcap'
    wrench_ns, forces, torques = downward_log(path, swap_stamps=(10, 200))
    trial = read_mcap_trial(path, WRENCH_TOPIC, POSE_TOPIC)
    np.testing.assert_allclose(trial.time_s, wrench_ns / 1e9, rtol=1e-16, atol=0)
    time_from_start = (wrench_ns - T0_NS) * 1e-9
    np.testing.assert_allclose(trial.travel_m, travel_at(time_from_start), atol=1e-12)
    np.testing.assert_allclose(trial.axial_force_n, axial_truth(time_from_start), atol=1e-12)
    np.testing.assert_allclose(trial.force_n, forces, atol=0)
    np.testing.assert_allclose(trial.torque_nm, torques, atol=0)


def test_mcap_tilted_transform_with_wrench_in_the_needle_frame(tmp_path):
    from tissue_sim_ros.io.trials.mcap_files import read_mcap_trial
    half = np.radians(30) / 2  # needle turned 30 deg about y: axis (sin 30, 0, cos 30)
    axis = np.array([np.sin(2 * half), 0.0, np.cos(2 * half)])
    path = tmp_path / 'tilted.mcap'
    wrench_ns, _, _ = write_robot_log(
        path, rotation_xyzw=(0.0, np.sin(half), 0.0, np.cos(half)),
        base_at=lambda t: tuple([0.01, 0.02, 0.1] + travel_at(t) * axis
                                + [0.0, 2e-3 * t, 0.0]),  # a drift across the axis
        force_at=lambda t: (0.1, 0.2, -axial_truth(t)),
        wrench_frame='needle_base', child_frame='needle_base')
    trial = read_mcap_trial(path, WRENCH_TOPIC, POSE_TOPIC)
    time_from_start = (wrench_ns - T0_NS) * 1e-9
    np.testing.assert_allclose(trial.travel_m, travel_at(time_from_start), atol=1e-12)
    np.testing.assert_allclose(trial.axial_force_n, axial_truth(time_from_start), atol=1e-12)


def test_mcap_wrench_in_another_frame_is_refused_unless_named(tmp_path):
    from tissue_sim_ros.io.trials.mcap_files import read_mcap_trial
    path = tmp_path / 'sensor_frame.mcap'
    wrench_ns, _, _ = downward_log(path, wrench_frame='ft_sensor')
    with pytest.raises(DataError, match="'ft_sensor' is neither the needle frame.*'world'.*"
                                        "wrench_frame"):
        read_mcap_trial(path, WRENCH_TOPIC, POSE_TOPIC)
    as_parent = read_mcap_trial(path, WRENCH_TOPIC, POSE_TOPIC, wrench_frame='parent')
    as_needle = read_mcap_trial(path, WRENCH_TOPIC, POSE_TOPIC, wrench_frame='needle', sign=1)
    time_from_start = (wrench_ns - T0_NS) * 1e-9
    np.testing.assert_allclose(as_parent.axial_force_n, axial_truth(time_from_start), atol=1e-12)
    np.testing.assert_allclose(as_needle.axial_force_n, axial_truth(time_from_start), atol=1e-12)


def test_mcap_missing_topic_names_the_topics_the_file_has(tmp_path):
    from tissue_sim_ros.io.trials.mcap_files import read_mcap_trial
    path = tmp_path / 'robot.mcap'
    downward_log(path)
    with pytest.raises(DataError) as err:
        read_mcap_trial(path, '/ft/wrench', POSE_TOPIC)
    assert err.value.column == '/ft/wrench' and str(path) in str(err.value)
    assert f'{WRENCH_TOPIC} (geometry_msgs/msg/WrenchStamped, 390)' in str(err.value)
    assert f'{POSE_TOPIC} (geometry_msgs/msg/PoseStamped, 101)' in str(err.value)


def still_log(path, **options):
    """A needle at rest, pressed with 1 N along its +z, the wrench in the needle frame."""
    return write_robot_log(path, rotation_xyzw=(0.0, 0.0, 0.0, 1.0), base_at=lambda t: (0, 0, 0),
                           force_at=lambda t: (0.0, 0.0, np.nan if 0.5 < t < 0.52 else 1.0),
                           wrench_frame='needle', **options)


def test_mcap_repeated_stamp_names_the_message_and_log_time_reads_it(tmp_path):
    from tissue_sim_ros.io.trials.mcap_files import read_mcap_trial
    path = tmp_path / 'robot.mcap'
    still_log(path, repeat_stamp=100)
    with pytest.raises(DataError) as err:
        read_mcap_trial(path, WRENCH_TOPIC, drop_nan_rows=True)
    assert (err.value.column, err.value.row) == (WRENCH_TOPIC, 102)
    assert 'repeats' in str(err.value)
    trial = read_mcap_trial(path, WRENCH_TOPIC, time_source='log', drop_nan_rows=True)
    assert trial.travel_m is None and np.all(trial.axial_force_n == -1.0)


def test_mcap_nan_wrenches_refused_or_dropped_and_counted(tmp_path):
    from tissue_sim_ros.io.trials.mcap_files import read_mcap_trial
    path = tmp_path / 'robot.mcap'
    wrench_ns, _, _ = still_log(path)
    time_s = (wrench_ns - T0_NS) * 1e-9
    nan_rows = np.flatnonzero((time_s > 0.5) & (time_s < 0.52)) + 1
    with pytest.raises(DataError) as err:
        read_mcap_trial(path, WRENCH_TOPIC, POSE_TOPIC)
    assert (err.value.column, err.value.row) == (WRENCH_TOPIC, nan_rows[0])
    assert f'{len(nan_rows)} row(s)' in str(err.value)
    trial = read_mcap_trial(path, WRENCH_TOPIC, POSE_TOPIC, drop_nan_rows=True)
    assert trial.nan_rows_dropped == len(nan_rows) == 4
    np.testing.assert_allclose(trial.time_s, np.delete(wrench_ns, nan_rows - 1) / 1e9, rtol=1e-16)
    assert np.all(trial.axial_force_n == -1.0) and np.all(trial.travel_m == 0.0)


def test_not_an_mcap_file(tmp_path):
    from tissue_sim_ros.io.trials.mcap_files import read_mcap_trial
    text = tmp_path / 'not.mcap'
    text.write_text('time,fz\n')
    with pytest.raises(DataError, match=f'{text}: not an MCAP file'):
        read_mcap_trial(text, WRENCH_TOPIC)
