"""Importing load-cell recordings (text and MCAP) into Trials in SI, checked against the arrays the
synthetic files were written from, in other units, signs, time origins and separators; unit
factors against their definitions; each bad file against the error it must get."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from tissue_sim_ros.errors import DataSpecError
from tissue_sim_ros.io.trials.measurement_units import to_si, unit_factor
from tissue_sim_ros.errors import UnitError
from tissue_sim_ros.io.trials.text_files import read_text_trial
from tissue_sim_ros.errors import DataError

# Independent definitions: standard gravity, the avoirdupois pound, the inch.
G0 = 9.80665
LBF_N = 0.45359237 * G0
INCH_M = 25.4e-3


@pytest.mark.parametrize('quantity, unit, si', [
    ('time', 's', 1.0), ('time', 'ms', 1e-3), ('time', 'us', 1e-6), ('time', 'µs', 1e-6),
    ('time', 'μs', 1e-6), ('time', 'ns', 1e-9),
    ('force', 'N', 1.0), ('force', 'mN', 1e-3), ('force', 'kN', 1e3), ('force', 'gf', 1e-3 * G0),
    ('force', 'kgf', G0), ('force', 'lbf', LBF_N), ('force', 'ozf', LBF_N / 16),
    ('torque', 'N m', 1.0), ('torque', 'Nm', 1.0), ('torque', 'N*m', 1.0), ('torque', 'N.m', 1.0),
    ('torque', 'N mm', 1e-3), ('torque', 'Nmm', 1e-3), ('torque', 'mN m', 1e-3),
    ('position', 'm', 1.0), ('position', 'cm', 1e-2), ('position', 'mm', 1e-3),
    ('position', 'um', 1e-6), ('position', 'µm', 1e-6), ('position', 'in', INCH_M),
    ('speed', 'm/s', 1.0), ('speed', 'mm/s', 1e-3), ('speed', 'um/s', 1e-6),
])
def test_unit_factor_matches_its_definition(quantity, unit, si):
    assert unit_factor(quantity, unit) == pytest.approx(si, rel=1e-15)
    assert to_si([2.0, -3.0], quantity, unit) == pytest.approx([2 * si, -3 * si], rel=1e-15)


def test_pound_force_is_the_published_value():
    assert unit_factor('force', 'lbf') == pytest.approx(4.4482216152605, rel=1e-14)


@pytest.mark.parametrize('quantity, unit', [('force', 'MN'), ('force', 'lb'), ('torque', 'N'),
                                            ('time', 'Hz'), ('position', 'furlong')])
def test_unknown_unit_names_quantity_unit_and_known_units(quantity, unit):
    with pytest.raises(UnitError) as err:
        unit_factor(quantity, unit)
    message = str(err.value)
    assert quantity in message and repr(unit) in message
    assert all(known in message for known in {'force': ['N', 'mN', 'lbf'], 'torque': ['N mm'],
                                              'time': ['ms', 'us'],
                                              'position': ['mm', 'in']}[quantity])


# -- a known insertion: insert, hold, retract -----------------------------------------------------

def known_insertion(n_samples=700, seed=3):
    """Sample times with 88-100 Hz jitter (whole microseconds from a timer that started at
    12.345678 s), travel [m] (2 mm/s to 10 mm, hold, retract), an axial force [N] that rises,
    drops at a puncture and goes negative in retraction, lateral forces and torques."""
    rng = np.random.default_rng(seed)
    steps_us = rng.integers(10_000, 11_364, n_samples - 1)
    time_us = 12_345_678 + np.concatenate([[0], np.cumsum(steps_us)])
    time_s = (time_us - time_us[0]) * 1e-6
    travel_m = np.clip(np.minimum(0.002 * time_s, 0.010 - 0.002 * (time_s - 4.5 - 1.5)), 0, 0.010)
    axial_n = 40 * travel_m + 0.3 * np.sin(3 * time_s) - 0.5 * (time_s > 3.5)
    axial_n[time_s > 6.0] = -0.2 - 20 * travel_m[time_s > 6.0]
    lateral_n = rng.normal(0, 0.05, (n_samples, 2))
    torque_nm = rng.normal(0, 2e-3, (n_samples, 3))
    return time_us, travel_m, axial_n, lateral_n, torque_nm


def write_table(path, header, columns, delimiter=',', preamble=()):
    """A text file: preamble lines, a header (None: none), then one row per sample."""
    lines = list(preamble)
    if header is not None:
        lines.append(delimiter.join(header))
    lines += [delimiter.join(f'{value!r}' for value in row)
              for row in zip(*[np.asarray(c).tolist() for c in columns])]
    path.write_text('\n'.join(lines) + '\n')
    return path


def test_six_axis_csv_in_microseconds_millinewtons_and_millimetres(tmp_path):
    time_us, travel_m, axial_n, lateral_n, torque_nm = known_insertion()
    stage_mm = 3.7 - 1e3 * travel_m  # the stage moves toward -z while inserting
    path = write_table(tmp_path / 'trial.csv', 'time,fx,fy,fz,tx,ty,tz,px,py,pz'.split(','), [
        time_us, 1e3 * lateral_n[:, 0], 1e3 * lateral_n[:, 1], -1e3 * axial_n,
        *(1e3 * torque_nm.T), np.zeros_like(time_us), np.zeros_like(time_us), stage_mm],
        preamble=['# exported by the rig logger', '# force in mN'])
    trial = read_text_trial(path, time={'column': 'time', 'unit': 'us'},
                            force={'column': 'fz', 'unit': 'mN', 'sign': -1},
                            torque={'columns': ['tx', 'ty', 'tz'], 'unit': 'N mm'},
                            position={'column': 'pz', 'unit': 'mm', 'sign': -1})
    np.testing.assert_allclose(trial.time_s, time_us * 1e-6, rtol=1e-15)  # origin kept
    np.testing.assert_allclose(trial.time_from_start_s, (time_us - time_us[0]) * 1e-6,
                               atol=1e-12)
    np.testing.assert_allclose(trial.axial_force_n, axial_n, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(trial.travel_m, travel_m, atol=1e-15)
    np.testing.assert_allclose(trial.torque_nm, torque_nm, rtol=1e-12, atol=1e-18)
    assert trial.force_n is None and trial.nan_rows_dropped == 0
    assert trial.axial_force_n.min() < 0 < trial.axial_force_n.max()  # retraction stays negative
    assert trial.sample_rate_hz == pytest.approx(1e6 / np.median(np.diff(time_us)))
    assert 88 <= trial.sample_rate_hz <= 100
    assert trial.duration_s == pytest.approx((time_us[-1] - time_us[0]) * 1e-6)


@pytest.mark.parametrize('reduce, direction', [('norm', None), ('projection', [0.0, 3.0, -4.0])])
def test_three_force_columns_reduced_like_numpy(tmp_path, reduce, direction):
    time_us, _, axial_n, lateral_n, _ = known_insertion(200)
    force_n = np.column_stack([lateral_n, axial_n])
    path = write_table(tmp_path / 'f.csv', ['t', 'Fx', 'Fy', 'Fz'],
                       [time_us * 1e-3, *(force_n / LBF_N).T])
    trial = read_text_trial(path, time={'column': 't', 'unit': 'ms'},
                            force={'columns': ['fx', 'fy', 'fz'], 'unit': 'lbf',
                                   'reduce': reduce, 'direction': direction})
    expected = (np.linalg.norm(force_n, axis=1) if reduce == 'norm'
                else force_n @ np.array([0.0, 0.6, -0.8]))
    np.testing.assert_allclose(trial.axial_force_n, expected, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(trial.force_n, force_n, rtol=1e-12, atol=1e-15)


def test_headerless_tsv_by_index_with_a_sample_rate(tmp_path):
    _, travel_m, axial_n, _, _ = known_insertion(300)
    path = write_table(tmp_path / 'rig.tsv', None,
                       [np.arange(300), axial_n / (1e-3 * G0), travel_m * 1e6], delimiter='\t')
    trial = read_text_trial(path, time={'rate_hz': 500}, force={'column': 1, 'unit': 'gf'},
                            position={'column': 2, 'unit': 'um'})
    np.testing.assert_allclose(trial.time_s, np.arange(300) / 500.0, rtol=1e-15)
    np.testing.assert_allclose(trial.axial_force_n, axial_n, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(trial.travel_m, travel_m, atol=1e-15)


def test_whitespace_file_with_preamble_comments_and_blank_lines(tmp_path):
    time_us, _, axial_n, _, _ = known_insertion(50)
    rows = [f'{t!r}   {f!r}' for t, f in zip((time_us * 1e-9).tolist(), (axial_n / G0).tolist())]
    rows[10:10] = ['  # operator paused the logger', '']
    path = tmp_path / 'rig.dat'
    path.write_text('Rig 3 export\nsample rate 100 Hz\nTime  Force\n' + '\n'.join(rows) + '\n')
    trial = read_text_trial(path, time={'column': 'time', 'unit': 's'},
                            force={'column': 'FORCE', 'unit': 'kgf'},
                            text_format={'skip_rows': 2})
    np.testing.assert_allclose(trial.time_s, time_us * 1e-9, rtol=1e-15)
    np.testing.assert_allclose(trial.axial_force_n, axial_n, rtol=1e-12, atol=1e-15)


def test_semicolon_file_matches_names_ignoring_case_and_spaces(tmp_path):
    time_us, _, axial_n, _, _ = known_insertion(40)
    path = write_table(tmp_path / 'eu.csv', [' Time (ms) ', ' Force (N) '],
                       [time_us * 1e-3, axial_n], delimiter=';')
    trial = read_text_trial(path, time={'column': 'TIME (MS)', 'unit': 'ms'},
                            force={'column': 'force (n)'})
    np.testing.assert_allclose(trial.axial_force_n, axial_n, rtol=1e-15)
    np.testing.assert_allclose(trial.time_s, time_us * 1e-6, rtol=1e-15)


# -- bad files ------------------------------------------------------------------------------------

TIME_US = {'column': 'time', 'unit': 'us'}
FORCE = {'column': 'fz'}


def read_lines(tmp_path, text, name='bad.csv', **options):
    path = tmp_path / name
    path.write_text(text)
    return path, lambda: read_text_trial(path, **{'time': TIME_US, 'force': FORCE, **options})


def assert_data_error(read, path, column, row, *words):
    with pytest.raises(DataError) as err:
        read()
    message = str(err.value)
    assert (err.value.file, err.value.column, err.value.row) == (str(path), column, row)
    assert str(path) in message
    assert column is None or repr(column) in message
    assert row is None or f'row {row}' in message
    assert all(word in message for word in words), message
    return message


def test_missing_column_lists_the_columns(tmp_path):
    path, read = read_lines(tmp_path, 'time,fx,fy\n0,1,2\n1,1,2\n')
    assert_data_error(read, path, 'fz', None, 'time, fx, fy')


def test_column_name_without_header_asks_for_an_index(tmp_path):
    path, read = read_lines(tmp_path, '0,1\n1,2\n')
    assert_data_error(read, path, 'time', None, 'no header', '0 to 1')


def test_index_out_of_range(tmp_path):
    path, read = read_lines(tmp_path, '0,1\n1,2\n', time={'column': 0}, force={'column': 5})
    assert_data_error(read, path, 5, None, '2 columns')


def test_cell_that_is_not_a_number(tmp_path):
    path, read = read_lines(tmp_path, '# comment\ntime,fz\n0,1.0\n10,"1,5"\n20,2.0\n')
    assert_data_error(read, path, 'fz', 4, "'1,5'")  # a decimal comma, quoted, is text


def test_time_going_backwards_names_the_row(tmp_path):
    path, read = read_lines(tmp_path, 'time,fz\n0,1\n10,1\n30,1\n20,1\n40,1\n')
    assert_data_error(read, path, 'time', 5, 'backwards', 'row 4')


def test_repeated_time_names_the_row(tmp_path):
    path, read = read_lines(tmp_path, 'time,fz\n0,1\n10,1\n10,2\n')
    assert_data_error(read, path, 'time', 4, 'repeats')


def test_nan_rows_refused_by_default_naming_the_first(tmp_path):
    text = 'time,fx,fz\n0,0,1\n10,0,2\n20,nan,3\n30,0,\n40,0,5\n50,0,6\n60,0\n'
    path, read = read_lines(tmp_path, text, force={'columns': ['fx', 'fx', 'fz']})
    assert_data_error(read, path, 'fx', 4, '3 row(s)', 'drop_nan_rows')


def test_nan_rows_dropped_and_counted_when_asked(tmp_path):
    text = 'time,fz,pz\n0,1,0\n10,2,1\n20,nan,2\n30,,3\n40,5,inf\n50,6,5\n60,7\n'
    path = tmp_path / 'nan.csv'
    path.write_text(text)
    trial = read_text_trial(path, time=TIME_US, force=FORCE,
                            position={'column': 'pz', 'unit': 'mm'}, drop_nan_rows=True)
    assert trial.nan_rows_dropped == 4
    np.testing.assert_allclose(trial.time_s, [0, 10e-6, 50e-6])
    np.testing.assert_allclose(trial.axial_force_n, [1, 2, 6])
    np.testing.assert_allclose(trial.travel_m, [0, 1e-3, 5e-3])


@pytest.mark.parametrize('text, words', [
    ('', ['no data rows']), ('# only a comment\n\n', ['no data rows']),
    ('time,fz\n', ['no data rows after the header']), ('time,fz\n0,1\n', ['1 sample']),
])
def test_empty_and_single_sample_files(tmp_path, text, words):
    path, read = read_lines(tmp_path, text)
    message = assert_data_error(read, path, None, 1 if 'header' in words[0] else None, *words)
    assert str(path) in message


def test_missing_file(tmp_path):
    path, read = read_lines(tmp_path, '')
    path.unlink()
    assert_data_error(read, path, None, None, 'cannot be read')


def test_unknown_unit_in_column_options_names_the_key(tmp_path):
    _, read = read_lines(tmp_path, 'time,fz\n0,1\n1,2\n', force={'column': 'fz', 'unit': 'lb'})
    with pytest.raises(DataSpecError, match=r"force\.unit: force unit 'lb' is not known; "
                                            r'known force units: N, mN, kN, gf, kgf, lbf, ozf'):
        read()


def test_io_modules_import_no_numba_and_no_rclpy():
    code = ('import sys\n'
            'import tissue_sim_ros.io.trials.data_spec, tissue_sim_ros.io.trials.mcap_files\n'
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('numba', 'rclpy')))")
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == '[]'


# -- MCAP: a robot log of WrenchStamped and PoseStamped / TransformStamped ------------------------

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
