"""Logs under bad conditions: malformed payloads, files cut short, hard kills; and the io layer
imports no numba. Truth comes from readers this project did not write (``rosbags``, the ``mcap``
library's records and summary) and from what the test itself wrote.
"""
import os
import signal
import statistics
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

pytest.importorskip('rclpy')

from mcap.reader import make_reader  # noqa: E402
from mcap.records import Chunk  # noqa: E402
from mcap.stream_reader import breakup_chunk  # noqa: E402
from mcap.data_stream import ReadDataStream  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from rosbags.highlevel import AnyReader  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from tissue_sim_ros.cli import app as cli  # noqa: E402
from tissue_sim_ros.io import mcap as ml  # noqa: E402
from tissue_sim_ros.ros.messages import conversions as cv  # noqa: E402
from tissue_sim_ros.units import NS_PER_S  # noqa: E402

T0 = 1_700_000_000_000_000_000
PERIOD = 20_000_000  # 50 Hz
POSE = 'geometry_msgs/msg/PoseStamped'
WRENCH = 'geometry_msgs/msg/WrenchStamped'


def _pose(i):
    from geometry_msgs.msg import PoseStamped
    msg = PoseStamped()
    msg.header.frame_id = 'world'
    msg.header.stamp = cv.ns_to_stamp(T0 + i * PERIOD)
    msg.pose.position.x = 0.001 * i
    msg.pose.position.z = -0.002 * i
    msg.pose.orientation.w = 1.0
    return msg


def _bad_payloads():
    """Payloads a buggy bridge or a bag replayed with the wrong type can put on needle/pose."""
    rng = np.random.default_rng(13)
    good = serialize_message(_pose(1))
    return {
        'empty': b'',
        '1 byte': b'\x00',
        '7 random bytes': rng.bytes(7),
        '64 random bytes': rng.bytes(64),
        'CDR header then garbage': b'\x00\x01\x00\x00' + rng.bytes(40),
        'CDR header only': b'\x00\x01\x00\x00',
        'valid pose cut in half': good[:len(good) // 2],
        'valid pose less its last byte': good[:-1],
    }


# -- undecodable payloads ------------------------------------------------------------------------

@pytest.fixture(scope='module')
def log_with_bad_poses(tmp_path_factory):
    """Good poses and wrenches with a bad payload on needle/pose after every third good pose."""
    path = tmp_path_factory.mktemp('bad') / 'bad.mcap'
    bad = list(_bad_payloads().items())
    good_times, bad_times = [], []
    with ml.McapRecorder(path, metadata={'scene': 's'}) as rec:
        rec.add_topic('needle/pose', POSE, {})
        rec.add_topic('needle/wrench', WRENCH, {})
        k = 0
        for i in range(30):
            t = T0 + i * PERIOD
            rec.write('needle/pose', serialize_message(_pose(i)), t)
            good_times.append(t)
            rec.write('needle/wrench',
                      serialize_message(cv.wrench_msg([i, 0, 0], [0, 0, 0], 'needle', t)), t + 1)
            if i % 3 == 2 and k < len(bad):
                rec.write('needle/pose', bad[k][1], t + 2)
                bad_times.append(t + 2)
                k += 1
    assert k == len(bad)
    return path, good_times, bad_times, bad


def test_bad_payloads_are_refused_by_an_independent_decoder():
    """The premise: rosbags refuses every bad payload and decodes the good pose."""
    store = get_typestore(Stores.ROS2_JAZZY)
    assert store.deserialize_cdr(serialize_message(_pose(3)), POSE).pose.position.x == 0.003
    for name, payload in _bad_payloads().items():
        with pytest.raises(Exception):
            store.deserialize_cdr(payload, POSE)
            pytest.fail(f'rosbags decoded the {name} payload')


def test_bad_payloads_are_recorded_verbatim(log_with_bad_poses):
    path, good_times, bad_times, bad = log_with_bad_poses
    with open(path, 'rb') as f:
        pose_payloads = {m.log_time: m.data for _, c, m in make_reader(f).iter_messages()
                         if c.topic == 'needle/pose'}
    assert [pose_payloads[t] for t in bad_times] == [payload for _, payload in bad]
    with AnyReader([path]) as reader:  # the file itself is sound: rosbags opens it
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts == {'needle/pose': len(good_times) + len(bad_times), 'needle/wrench': 30}


@pytest.mark.parametrize('truncated', [False, True])
def test_read_log_skips_and_reports_undecodable_messages(log_with_bad_poses, tmp_path, truncated):
    path, good_times, bad_times, _ = log_with_bad_poses
    if truncated:  # every chunk, no summary: the stream-read path
        with open(path, 'rb') as f:
            last = make_reader(f).get_summary().chunk_indexes[-1]
        path = tmp_path / 'torn.mcap'
        path.write_bytes(log_with_bad_poses[0].read_bytes()[:last.chunk_start_offset
                                                           + last.chunk_length])
    reading = ml.read_log(path, allow_truncated=truncated)
    messages = list(reading)
    poses = [m for m in messages if m.topic == 'needle/pose']
    assert [m.log_time_ns for m in poses] == good_times
    for i, m in enumerate(poses):  # each good pose equals the one written
        ref = _pose(i)
        p = m.message.pose.position
        assert (p.x, p.y, p.z) == (ref.pose.position.x, ref.pose.position.y, ref.pose.position.z)
        assert m.message.header.frame_id == 'world'
        assert (m.message.header.stamp.sec, m.message.header.stamp.nanosec) == \
            (ref.header.stamp.sec, ref.header.stamp.nanosec)
    wrenches = [m for m in messages if m.topic == 'needle/wrench']
    assert [m.message.wrench.force.x for m in wrenches] == [float(i) for i in range(30)]
    report = reading.undecodable
    assert set(report) == {'needle/pose'} and reading.skipped == len(bad_times)
    assert report['needle/pose'].count == len(bad_times)
    assert report['needle/pose'].first_log_times_ns == bad_times[:5]
    assert report['needle/pose'].first_error


def test_read_log_on_good_topics_reports_nothing(log_with_bad_poses):
    path = log_with_bad_poses[0]
    reading = ml.read_log(path, topics=['needle/wrench'])
    assert len(list(reading)) == 30 and reading.undecodable == {} and reading.skipped == 0


# -- recover: files cut at many places -----------------------------------------------------------

@pytest.fixture(scope='module')
def complete_log(tmp_path_factory):
    """A closed log of 120 wrenches and 40 poses with short chunks (0.2 s of log time)."""
    path = tmp_path_factory.mktemp('rec') / 'run.mcap'
    with ml.McapRecorder(path, metadata={'scene': 'cut'}, chunk_interval_s=0.2,
                         background=False) as rec:
        rec.add_topic('needle/wrench', WRENCH, {'depth': 10})
        rec.add_topic('needle/pose', POSE, None)
        for i in range(120):
            t = T0 + i * PERIOD
            rec.write('needle/wrench',
                      serialize_message(cv.wrench_msg([i, 0, 0], [0, 0, 0], 'needle', t)), t)
            if i % 3 == 0:
                rec.write('needle/pose', serialize_message(_pose(i)), t + 5)
    return path


def _chunks(path):
    """(start offset, end offset, message count, message_end_time) of each chunk, read with the
    mcap library from the file's own chunk index."""
    out = []
    with open(path, 'rb') as f:
        indexes = make_reader(f).get_summary().chunk_indexes
        for ci in indexes:
            f.seek(ci.chunk_start_offset + 1 + 8)
            chunk = Chunk.read(ReadDataStream(f))
            count = sum(type(r).__name__ == 'Message' for r in breakup_chunk(chunk))
            out.append((ci.chunk_start_offset, ci.chunk_start_offset + ci.chunk_length, count,
                        ci.message_end_time))
    return out


def _raw_messages(path):
    with AnyReader([path]) as reader:
        return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]


def test_recover_command_on_a_log_cut_at_many_places(complete_log, tmp_path, capsys):
    body = complete_log.read_bytes()
    chunks = _chunks(complete_log)
    assert len(chunks) >= 8
    original = sorted(_raw_messages(complete_log), key=lambda m: m[1])
    in_file_order = []  # by chunk, as written
    with open(complete_log, 'rb') as f:
        for _, c, m in make_reader(f).iter_messages(log_time_order=False):
            in_file_order.append((c.topic, m.log_time, bytes(m.data)))
    assert sorted(in_file_order, key=lambda m: m[1]) == original
    k = len(chunks) // 2
    cuts = {
        'inside the header': 40,
        'between two chunks': chunks[k][0],
        'inside a chunk': (chunks[k][0] + chunks[k][1]) // 2,
        'inside the last chunk': (chunks[-1][0] + chunks[-1][1]) // 2,
        'inside the summary': len(body) - 60,
    }
    for name, cut in cuts.items():
        torn = tmp_path / f'{name.replace(" ", "_")}.mcap'
        torn.write_bytes(body[:cut])
        out = tmp_path / f'{torn.stem}.repaired.mcap'
        assert cli.main(['recover', str(torn), '--out', str(out)]) == 0
        line = capsys.readouterr().out.strip()
        expected = sum(n for start, end, n, _ in chunks if end <= cut)
        recovered = _raw_messages(out)  # rosbags reads the repaired copy completely
        assert recovered == in_file_order[:expected], name
        assert f'kept {expected} messages' in line and '\n' not in line, line
        if name == 'inside a chunk':
            last_kept = in_file_order[expected - 1][1]
            lost = (chunks[k][3] - last_kept) / NS_PER_S
            assert f'lost at the end: at least {lost:.3f} s' in line, line
        if name == 'between two chunks':
            assert 'not recorded in the file' in line, line
        if name == 'inside the summary':
            assert expected == len(in_file_order) and 'nothing lost' in line, line
        assert ml.read_metadata(out).get('scene') == ('cut' if cut > 200 else None)


def test_recover_command_default_output_and_refusals(complete_log, tmp_path):
    """The console command: default output name, one-line errors with exit status 2."""
    torn = tmp_path / 'torn.mcap'
    torn.write_bytes(complete_log.read_bytes()[:len(complete_log.read_bytes()) // 2])
    (tmp_path / 'text.mcap').write_text('not a log\n')

    def run(*args):
        return subprocess.run([sys.executable, '-m', 'tissue_sim_ros.cli', 'recover', *args],
                              capture_output=True, text=True, timeout=60)
    ok = run(str(torn))
    assert ok.returncode == 0, ok.stderr
    assert (tmp_path / 'torn.recovered.mcap').is_file() and 'wrote' in ok.stdout
    for args, words in (([str(tmp_path / 'missing.mcap')], 'No such file'),
                        ([str(tmp_path / 'text.mcap')], 'not an MCAP'),
                        ([str(torn)], 'exists'),  # the default output is there now
                        ([str(tmp_path)], 'directory')):
        r = run(*args)
        assert r.returncode == 2, (args, r.stdout, r.stderr)
        assert r.stderr.startswith('tissue-sim recover: error:') and words in r.stderr, r.stderr
        assert 'Traceback' not in r.stderr and r.stderr.count('\n') == 1, r.stderr


# -- kill -9: the loss bound ---------------------------------------------------------------------

_WRITER = textwrap.dedent('''
    import sys, time
    from rclpy.serialization import serialize_message
    from tissue_sim_ros.io.mcap import McapRecorder
    from tissue_sim_ros.ros.messages import conversions as cv
    rec = McapRecorder(sys.argv[1], metadata={'scene': 'kill'}, chunk_interval_s=float(sys.argv[2]))
    rec.add_topic('needle/wrench', 'geometry_msgs/msg/WrenchStamped', {})
    period, start, i = 0.02, time.monotonic(), 0
    print('ready', flush=True)
    while True:  # 50 Hz on the real clock; log time = wall time
        t = time.time_ns()
        msg = cv.wrench_msg([float(i), 0.0, 0.0], [0.0, 0.0, 0.0], 'needle', t)
        rec.write('needle/wrench', serialize_message(msg), t)
        print(i, t, flush=True)
        i += 1
        time.sleep(max(0.0, start + i * period - time.monotonic()))
''')


def test_sigkill_just_before_a_chunk_closes_loses_less_than_the_interval(tmp_path):
    """The worst moment for a hard kill: just before the writer would close its chunk (the file
    is about to grow). The bound (mcap_chunk_age.ChunkAge): every message written more than
    chunk_interval_s / 2 + d before the kill is in the file, d the writer's delay; the promise
    is chunk_interval_s. Asserted: lost <= interval / 2 + one period + 0.2 s for d. (Closing at
    the full interval, as before, lost 0.98 s here.)"""
    interval = 1.0
    path = tmp_path / 'killed.mcap'
    proc = subprocess.Popen([sys.executable, '-c', _WRITER, str(path), str(interval)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == 'ready', proc.stderr.read()
        size, growths, target = path.stat().st_size, [], None
        deadline = time.monotonic() + 8.0
        while time.monotonic() < deadline:
            now = time.monotonic()
            grown = path.stat().st_size
            if grown != size:  # a chunk was closed
                size = grown
                growths.append(now)
                if len(growths) >= 3:
                    gap = statistics.median(b - a for a, b in zip(growths, growths[1:]))
                    target = now + gap - 0.03
            if target is not None and now >= target:
                break
            time.sleep(0.002)
        else:
            pytest.fail(f'no steady chunk closing seen: {growths}')
        os.kill(proc.pid, signal.SIGKILL)
        out, err = proc.communicate(timeout=10)
    finally:
        proc.kill()
    assert proc.returncode == -signal.SIGKILL
    printed = [line.split() for line in out.splitlines()]
    last_written_ns = int(printed[-1][1]) + PERIOD  # one more may be written, not yet printed
    report = ml.recover_truncated(path)
    recovered = [int(m.message.wrench.force.x) for m in ml.read_log(path, allow_truncated=True)]
    assert recovered == list(range(len(recovered))) and len(recovered) >= 50  # an intact prefix
    lost_s = (last_written_ns - report['last_log_time_ns']) / NS_PER_S
    print(f'kill -9 just before a chunk close: lost {lost_s:.3f} s of log '
          f'(chunk_interval_s {interval}; chunks closed every {gap:.3f} s)')
    assert lost_s <= interval / 2 + PERIOD / NS_PER_S + 0.2, (lost_s, gap)
    assert lost_s <= interval  # the promise
    ml.recover_truncated(path, tmp_path / 'repaired.mcap')
    with AnyReader([tmp_path / 'repaired.mcap']) as reader:
        assert sum(c.msgcount for c in reader.connections) == len(recovered)


# -- layering ------------------------------------------------------------------------------------

_NO_NUMBA = textwrap.dedent('''
    import os, sys
    import tissue_sim_ros
    from tissue_sim_ros.io import mcap as mcap_log
    from tissue_sim_ros.io.mcap import reader as mcap_reader
    from tissue_sim_ros.io.mcap import recovery as mcap_recovery
    from tissue_sim_ros.io.mcap import writer as mcap_writer
    from tissue_sim_ros.io.mcap import message_definitions as ros_message_definitions
    from tissue_sim_ros.io.mcap import rosbag2_qos
    path = sys.argv[1]
    with mcap_log.McapRecorder(path, metadata={'scene': 'x'}) as rec:
        rec.add_topic('t', 'std_msgs/msg/UInt8', {})
        for i in range(5):
            rec.write('t', bytes([0, 1, 0, 0, i]), 1000 + i)
    values = [m.message.data for m in mcap_log.read_log(path)]
    assert values == list(range(5)), values
    assert mcap_log.recover_truncated(path)['complete']
    assert mcap_log.read_metadata(path)['package_version'] == tissue_sim_ros.__version__
    loaded = sorted(m for m in sys.modules if m.split('.')[0] in ('numba', 'llvmlite')
                    or m.startswith('tissue_sim_ros.engine'))
    print('loaded:', loaded)
    ts = tissue_sim_ros  # then the engine names still load on first use, policy applied
    from tissue_sim_ros import SimulationDiverged
    import numba
    assert ts.Material(3000.0, 0.45, 1000.0).young_modulus == 3000.0
    assert issubclass(SimulationDiverged, Exception) and 'Simulation' in dir(ts)
    print('layer:', numba.config.THREADING_LAYER, os.environ.get('GOMP_SPINCOUNT'))
''')


def test_writing_and_reading_a_log_imports_no_numba(tmp_path):
    env = {k: v for k, v in os.environ.items()
           if k not in ('NUMBA_THREADING_LAYER', 'GOMP_SPINCOUNT', 'OMP_WAIT_POLICY')}
    r = subprocess.run([sys.executable, '-c', _NO_NUMBA, str(tmp_path / 'x.mcap')], env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert 'loaded: []' in r.stdout, r.stdout
    assert 'layer: omp 10000' in r.stdout, r.stdout


def test_numba_imported_before_the_engine_still_gets_the_threading_policy():
    env = {k: v for k, v in os.environ.items() if k != 'NUMBA_THREADING_LAYER'}
    code = ('import numba\nfrom tissue_sim_ros.engine import mesh\n'
            'print(numba.config.THREADING_LAYER)')
    r = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == 'omp', (r.stdout, r.stderr)


def test_one_parser_for_ros_type_names():
    from tissue_sim_ros.io.mcap.message_definitions import parse_type_name
    from tissue_sim_ros.ros.messages.from_yaml import message_type
    from geometry_msgs.msg import PoseStamped
    from std_srvs.srv import Trigger
    assert tuple(parse_type_name('geometry_msgs/msg/Pose')) == ('geometry_msgs', 'msg', 'Pose')
    assert tuple(parse_type_name('geometry_msgs/Pose')) == ('geometry_msgs', 'msg', 'Pose')
    assert message_type(POSE) is PoseStamped
    assert message_type('std_srvs/srv/Trigger', 'Request') is Trigger.Request
    for bad in ('geometry_msgs/Pose', 'geometry_msgs/msg/Pose/x', 'a b/msg/C', 'pkg/idl/X'):
        with pytest.raises(ValueError, match='type: '):
            message_type(bad)
    with pytest.raises(ValueError, match='type_name'):
        parse_type_name('geometry_msgs//Pose')
