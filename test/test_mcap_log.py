"""MCAP recording and reading, checked with readers this project did not write.

Independent readers: ``rosbags`` (AnyReader on the bare .mcap, its own .msg parser and CDR
decoder), the ``mcap`` package's reader (records, summary, metadata), and, where Node.js and npm
are present, the TypeScript ``@mcap/core`` reader used by Foxglove/Lichtblick, with CRC checks.
"""
import datetime as dt
import os
import re
import shutil
import signal
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest
import yaml

pytest.importorskip('rclpy')

from mcap.reader import make_reader  # noqa: E402
from mcap.stream_reader import StreamReader  # noqa: E402
from mcap.writer import Writer  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from rosbags.highlevel import AnyReader  # noqa: E402
from rosbags.rosbag2.metadata import QosDurability, QosReliability  # noqa: E402
from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402

import tissue_sim_ros  # noqa: E402
from tissue_sim_ros.io import mcap as ml  # noqa: E402
from tissue_sim_ros.ros.messages import conversions as cv  # noqa: E402

T0 = 1_700_000_000_000_000_000  # ns
PERIOD = 20_000_000  # 50 Hz

WRENCH = 'geometry_msgs/msg/WrenchStamped'
CLOUD = 'sensor_msgs/msg/PointCloud2'
MESH = 'shape_msgs/msg/Mesh'
MARKER = 'visualization_msgs/msg/Marker'
DIAG = 'diagnostic_msgs/msg/DiagnosticArray'
POSE = 'geometry_msgs/msg/PoseStamped'

TOPICS = {
    'needle/wrench': (WRENCH, {'reliability': 'reliable', 'durability': 'volatile', 'depth': 10}),
    'tissue/nodes': (CLOUD, {'reliability': 'reliable', 'durability': 'volatile', 'depth': 2}),
    'tissue/surface': (MESH, {'reliability': 'reliable', 'durability': 'transient_local',
                              'depth': 1}),
    'tissue/marker': (MARKER, {'reliability': 'reliable', 'depth': 1}),
    '/diagnostics': (DIAG, {'reliability': 'reliable', 'depth': 10}),
    'needle/pose': (POSE, None),
}


def _pose(i):
    from geometry_msgs.msg import PoseStamped
    msg = PoseStamped()
    msg.header.frame_id = 'world'
    msg.header.stamp = cv.ns_to_stamp(T0 + i * PERIOD)
    msg.pose.position.z = -0.001 * i
    msg.pose.orientation.w = 1.0
    return msg


def _sample(topic, i, rng_seed=7):
    """The i-th message of a topic, with values that depend on i."""
    rng = np.random.default_rng(rng_seed + i)
    stamp = T0 + i * PERIOD
    positions = rng.uniform(-0.02, 0.02, (40, 3))
    triangles = np.arange(60).reshape(20, 3) % 40
    if topic == 'needle/wrench':
        return cv.wrench_msg([0.1 * i, -0.2, 1.5 + i], [0.0, 0.001 * i, 0.0], 'needle', stamp)
    if topic == 'tissue/nodes':
        return cv.point_cloud_msg(positions, positions * 1e-2, 'tissue', stamp)
    if topic == 'tissue/surface':
        return cv.surface_mesh_msg(positions, triangles)
    if topic == 'tissue/marker':
        return cv.surface_marker_msg(positions, triangles, 'tissue', stamp, max_triangles=8)
    if topic == '/diagnostics':
        return cv.diagnostic_array_msg(stamp, [('engine', i % 4, f'tick {i}', {'i': i})])
    return _pose(i)


def _record(path, n=5, **kwargs):
    """Record n messages per topic (log time T0 + k*PERIOD, topics interleaved); return them."""
    written = []
    meta = {'scene': 'mesh: cube\nyoung_modulus_pa: 3000\n', 'parameters': 'publish_rate_hz: 50'}
    with ml.McapRecorder(path, metadata=meta, **kwargs) as rec:
        for topic, (type_name, qos) in TOPICS.items():
            rec.add_topic(topic, type_name, qos)
        for i in range(n):
            for j, topic in enumerate(TOPICS):
                data = serialize_message(_sample(topic, i))
                log_time = T0 + i * PERIOD + j * 1000
                rec.write(topic, data, log_time, publish_time_ns=log_time - 500)
                written.append((topic, TOPICS[topic][0], log_time, data, i))
    return written


@pytest.fixture(scope='module')
def recorded(tmp_path_factory):
    path = tmp_path_factory.mktemp('rec') / 'run.mcap'
    return path, _record(path)


# -- round trip -------------------------------------------------------------------------------

def _check_values(topic, msg, i):
    """Field values of a decoded message (rosbags or mcap_ros2 object) against _sample(i)."""
    ref = _sample(topic, i)
    if topic == 'needle/wrench':
        f = msg.wrench.force
        assert (f.x, f.y, f.z) == (ref.wrench.force.x, ref.wrench.force.y, ref.wrench.force.z)
        assert msg.wrench.torque.y == ref.wrench.torque.y
        assert msg.header.frame_id == 'needle'
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == \
            (ref.header.stamp.sec, ref.header.stamp.nanosec)
    elif topic == 'tissue/nodes':
        assert bytes(msg.data) == bytes(ref.data)
        assert [f.name for f in msg.fields] == ['x', 'y', 'z', 'ux', 'uy', 'uz']
        p, u = cv.point_cloud_arrays(msg)
        p_ref, u_ref = cv.point_cloud_arrays(ref)
        np.testing.assert_array_equal(p, p_ref)
        np.testing.assert_array_equal(u, u_ref)
    elif topic == 'tissue/surface':
        got = [(v.x, v.y, v.z) for v in msg.vertices]
        assert got == [(v.x, v.y, v.z) for v in ref.vertices]
        assert [list(t.vertex_indices) for t in msg.triangles] == \
            [t.vertex_indices.tolist() for t in ref.triangles]
    elif topic == 'tissue/marker':
        assert msg.type == 11 and len(msg.points) == len(ref.points) == 3 * 7
        assert [(p.x, p.y, p.z) for p in msg.points] == [(p.x, p.y, p.z) for p in ref.points]
    elif topic == '/diagnostics':
        status = msg.status[0]
        level = status.level
        level = level[0] if isinstance(level, (bytes, bytearray)) else int(level)
        assert level == i % 4
        assert status.message == f'tick {i}'
        assert [(kv.key, kv.value) for kv in status.values] == [('i', str(i))]
    else:
        assert msg.pose.position.z == -0.001 * i and msg.header.frame_id == 'world'


def test_round_trip_with_rosbags(recorded):
    path, written = recorded
    with AnyReader([path]) as reader:  # the bare .mcap, no metadata.yaml
        conns = {c.topic: c for c in reader.connections}
        assert set(conns) == set(TOPICS)
        for topic, (type_name, _) in TOPICS.items():
            assert conns[topic].msgtype == type_name
            assert conns[topic].msgcount == 5
        got = []
        for conn, timestamp, raw in reader.messages():
            got.append((conn.topic, conn.msgtype, timestamp, bytes(raw)))
            i = (timestamp - T0) // PERIOD
            _check_values(conn.topic, reader.deserialize(raw, conn.msgtype), i)
    assert sorted(got) == sorted((t, ty, lt, d) for t, ty, lt, d, _ in written)


def test_round_trip_with_read_log(recorded):
    path, written = recorded
    got = list(ml.read_log(path))
    assert [(m.topic, m.type_name, m.log_time_ns) for m in got] == \
        [(t, ty, lt) for t, ty, lt, _, _ in written]  # written in log-time order
    for (topic, _, _, _, i), m in zip(written, got):
        _check_values(topic, m.message, i)
    only = list(ml.read_log(path, topics=['needle/wrench']))
    assert len(only) == 5 and {m.topic for m in only} == {'needle/wrench'}


def test_payloads_and_publish_times_stored_verbatim(recorded):
    path, written = recorded
    with open(path, 'rb') as f:
        reader = make_reader(f)
        records = [(c.topic, m.log_time, m.publish_time, m.data, m.sequence)
                   for _, c, m in reader.iter_messages(log_time_order=False)]
    assert [(t, lt, lt - 500, d) for t, _, lt, d, _ in written] == [r[:4] for r in records]
    by_topic = {}
    for topic, *_, seq in records:
        by_topic.setdefault(topic, []).append(seq)
    assert all(seqs == [1, 2, 3, 4, 5] for seqs in by_topic.values())


# -- file structure ---------------------------------------------------------------------------

def test_profile_encodings_summary_and_statistics(recorded):
    path, written = recorded
    with open(path, 'rb') as f:
        reader = make_reader(f)
        header = reader.get_header()
        summary = reader.get_summary()
    assert header.profile == 'ros2'
    assert {s.name for s in summary.schemas.values()} == {ty for ty, _ in TOPICS.values()}
    assert {s.encoding for s in summary.schemas.values()} == {'ros2msg'}
    assert {c.message_encoding for c in summary.channels.values()} == {'cdr'}
    stats = summary.statistics
    assert stats.message_count == len(written) == 30
    counts = {summary.channels[cid].topic: n for cid, n in stats.channel_message_counts.items()}
    assert counts == {topic: 5 for topic in TOPICS}
    assert stats.message_start_time == written[0][2] and stats.message_end_time == written[-1][2]
    assert stats.chunk_count == len(summary.chunk_indexes) >= 1
    assert {c.compression for c in summary.chunk_indexes} == {'zstd'}
    assert stats.metadata_count == 1


def test_summarize_log(recorded):
    path, written = recorded
    s = ml.summarize_log(path)
    assert s['profile'] == 'ros2' and s['message_count'] == 30
    assert s['statistics']['message_count'] == 30
    assert s['statistics']['channel_message_counts'] == {t: 5 for t in TOPICS}
    for topic, (type_name, _) in TOPICS.items():
        entry = s['topics'][topic]
        times = [lt for t, _, lt, _, _ in written if t == topic]
        assert (entry['type'], entry['count']) == (type_name, 5)
        assert (entry['first_log_time_ns'], entry['last_log_time_ns']) == (times[0], times[-1])
    assert s['duration_s'] == pytest.approx((written[-1][2] - written[0][2]) / 1e9)


def test_offered_qos_profiles_in_channel_metadata(recorded):
    path, _ = recorded
    with open(path, 'rb') as f:
        channels = {c.topic: c for c in make_reader(f).get_summary().channels.values()}
    for topic, (_, qos) in TOPICS.items():
        text = channels[topic].metadata['offered_qos_profiles']
        if qos is None:
            assert text == ''
            continue
        profiles = yaml.safe_load(text)
        assert isinstance(profiles, list) and len(profiles) == 1
        p = profiles[0]
        assert p['reliability'] == qos['reliability']
        assert p['durability'] == qos.get('durability', 'volatile')
        assert p['history'] == 'keep_last' and p['depth'] == qos['depth']
        for key in ('deadline', 'lifespan', 'liveliness_lease_duration'):
            assert p[key] == {'sec': 0, 'nsec': 0}
        assert set(p) == {'history', 'depth', 'reliability', 'durability', 'deadline',
                          'lifespan', 'liveliness', 'liveliness_lease_duration',
                          'avoid_ros_namespace_conventions'}
    # rosbags parses the same YAML with its own rosbag2 QoS parser
    with AnyReader([path]) as reader:
        conns = {c.topic: c for c in reader.connections}
        surface = conns['tissue/surface'].ext.offered_qos_profiles[0]
        wrench = conns['needle/wrench'].ext.offered_qos_profiles[0]
    assert surface.durability == QosDurability.TRANSIENT_LOCAL
    assert surface.reliability == QosReliability.RELIABLE and surface.depth == 1
    assert wrench.durability == QosDurability.VOLATILE


def test_qos_profile_validation():
    p = ml.qos_profile({'reliability': 'BEST_EFFORT', 'deadline_ns': 1_500_000_000})
    assert p['reliability'] == 'best_effort' and p['deadline'] == {'sec': 1, 'nsec': 500_000_000}
    with pytest.raises(ValueError, match='unknown keys'):
        ml.qos_profile({'durabilty': 'transient_local'})
    with pytest.raises(ValueError, match='qos.durability'):
        ml.qos_profile({'durability': 'latched'})
    assert ml.qos_profiles_yaml(None) == ''
    assert '&' not in ml.qos_profiles_yaml({})  # no YAML anchors for rosbag2's yaml-cpp


def test_qos_from_rclpy_profile_is_accepted():
    from rclpy.qos import DurabilityPolicy, QoSProfile
    d = cv.qos_to_dict(QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    p = ml.qos_profile(d)
    assert (p['durability'], p['depth'], p['history']) == ('transient_local', 1, 'keep_last')


def test_metadata_record(recorded):
    path, _ = recorded
    with open(path, 'rb') as f:
        records = list(make_reader(f).iter_metadata())
    assert [r.name for r in records] == ['tissue_sim']
    assert records[0].metadata == {
        'scene': 'mesh: cube\nyoung_modulus_pa: 3000\n', 'parameters': 'publish_rate_hz: 50',
        'package_version': tissue_sim_ros.__version__}
    assert ml.read_metadata(path) == records[0].metadata
    assert ml.read_metadata(path, name=None) == {'tissue_sim': records[0].metadata}


def test_metadata_must_be_strings(tmp_path):
    with pytest.raises(TypeError, match="metadata\\['parameters'\\]"):
        ml.McapRecorder(tmp_path / 'x.mcap', metadata={'parameters': {'a': 1}})
    assert not (tmp_path / 'x.mcap').exists()


# -- schema text ------------------------------------------------------------------------------

def test_wrench_schema_text_has_each_dependency_once():
    text = ml.message_definition(WRENCH)
    root = ml.msg_file(WRENCH).read_text()
    assert text.startswith(root.rstrip())
    separators = [line for line in text.splitlines() if line.startswith('=')]
    assert separators == ['=' * 80] * 4
    msg_lines = [line for line in text.splitlines() if line.startswith('MSG: ')]
    assert sorted(msg_lines) == sorted([
        'MSG: std_msgs/Header', 'MSG: builtin_interfaces/Time', 'MSG: geometry_msgs/Wrench',
        'MSG: geometry_msgs/Vector3'])
    # every separator is followed by its MSG line, and that by the type's own .msg
    blocks = text.split('=' * 80 + '\n')[1:]
    for block in blocks:
        first, rest = block.split('\n', 1)
        pkg, name = first[len('MSG: '):].split('/')
        assert rest.rstrip() == ml.msg_file(f'{pkg}/{name}').read_text().rstrip()


def test_rosbags_deserializes_from_the_schema_text():
    """An empty rosbags type store, filled only from our text, decodes rclpy's CDR bytes."""
    for type_name, msg in ((WRENCH, _sample('needle/wrench', 3)),
                           (MARKER, _sample('tissue/marker', 2)),
                           (DIAG, _sample('/diagnostics', 1))):
        store = get_typestore(Stores.EMPTY)
        store.register(get_types_from_msg(ml.message_definition(type_name), type_name))
        decoded = store.deserialize_cdr(serialize_message(msg), type_name)
        topic = {WRENCH: 'needle/wrench', MARKER: 'tissue/marker', DIAG: '/diagnostics'}[type_name]
        _check_values(topic, decoded, {WRENCH: 3, MARKER: 2, DIAG: 1}[type_name])


def test_type_name_forms_and_errors():
    assert ml.schema_name('geometry_msgs/Wrench') == 'geometry_msgs/msg/Wrench'
    assert ml.message_definition('geometry_msgs/Wrench') == \
        ml.message_definition('geometry_msgs/msg/Wrench')
    with pytest.raises(ValueError, match='type_name'):
        ml.schema_name('geometry_msgs/srv/Foo/Bar')
    with pytest.raises(FileNotFoundError, match='no_such_msgs/msg/Thing.msg'):
        ml.message_definition('no_such_msgs/msg/Thing')


def test_msg_files_found_through_ament_prefix_path(tmp_path, monkeypatch):
    """A ROS install or workspace: the .msg files found under $AMENT_PREFIX_PATH/share."""
    share = tmp_path / 'prefix' / 'share' / 'zz_test_probe_msgs' / 'msg'
    share.mkdir(parents=True)
    (share / 'Probe.msg').write_text(
        '# a probe\nstd_msgs/Header header\nReading[<=4] readings\nstring<=8 label\n')
    (share / 'Reading.msg').write_text('float64 value  # N\ngeometry_msgs/Point where\n')
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(tmp_path / 'prefix'))
    text = ml.message_definition('zz_test_probe_msgs/msg/Probe')
    msg_lines = [line for line in text.splitlines() if line.startswith('MSG: ')]
    assert msg_lines == ['MSG: std_msgs/Header', 'MSG: builtin_interfaces/Time',
                         'MSG: zz_test_probe_msgs/Reading', 'MSG: geometry_msgs/Point']
    types = get_types_from_msg(text, 'zz_test_probe_msgs/msg/Probe')  # parses as a whole
    assert 'zz_test_probe_msgs/msg/Reading' in types


# -- recorder behaviour ----------------------------------------------------------------------

def test_new_log_path_names_and_never_overwrites(tmp_path):
    now = dt.datetime(2026, 11, 21, 14, 5, 3, tzinfo=dt.timezone.utc)
    d = tmp_path / 'logs' / 'deep'
    p1 = ml.new_log_path(d, now=now)
    assert p1 == d / 'tissue_sim_2026-11-21T14-05-03Z.mcap' and d.is_dir()
    p1.write_bytes(b'taken')
    p2 = ml.new_log_path(d, now=now)
    assert p2.name == 'tissue_sim_2026-11-21T14-05-03Z_1.mcap'
    with pytest.raises(FileExistsError):
        ml.McapRecorder(p1, metadata={})
    assert p1.read_bytes() == b'taken'
    local = dt.datetime(2026, 11, 21, 15, 5, 3, tzinfo=dt.timezone(dt.timedelta(hours=1)))
    assert ml.new_log_path(tmp_path, prefix='run', now=local).name == \
        'run_2026-11-21T14-05-03Z.mcap'


def test_create_in_directory_gives_distinct_files(tmp_path):
    with ml.McapRecorder.create(tmp_path, metadata={}) as a, \
            ml.McapRecorder.create(tmp_path, metadata={}) as b:
        assert a.path != b.path
        name = r'tissue_sim_\d{4}-\d\d-\d\dT\d\d-\d\d-\d\dZ(_\d+)?\.mcap'
        assert re.fullmatch(name, a.path.name)


def test_misuse_is_refused(tmp_path):
    rec = ml.McapRecorder(tmp_path / 'm.mcap', metadata={})
    cid = rec.add_topic('needle/wrench', WRENCH, {})
    assert rec.add_topic('needle/wrench', 'geometry_msgs/WrenchStamped', {}) == cid
    with pytest.raises(ValueError, match='already recorded as geometry_msgs/msg/WrenchStamped'):
        rec.add_topic('needle/wrench', POSE, {})
    with pytest.raises(ValueError, match="topic 'other' was not added"):
        rec.write('other', b'\0\1\0\0', T0)
    with pytest.raises(TypeError, match='cdr_bytes'):
        rec.write('needle/wrench', 'text', T0)
    with pytest.raises(ValueError, match='log_time_ns'):
        rec.write('needle/wrench', b'\0\1\0\0', -1)
    rec.close()
    rec.close()  # idempotent
    with pytest.raises(RuntimeError, match='closed'):
        rec.write('needle/wrench', b'\0\1\0\0', T0)
    with pytest.raises(ValueError, match='chunk_interval_s'):
        ml.McapRecorder(tmp_path / 'n.mcap', metadata={}, chunk_interval_s=0)


def test_concurrent_writers(tmp_path):
    path = tmp_path / 'threads.mcap'
    n_threads, per_thread = 4, 150
    data = serialize_message(_sample('needle/wrench', 0))
    with ml.McapRecorder(path, metadata={}, chunk_size=4096) as rec:
        rec.add_topic('shared', WRENCH, {})
        for k in range(n_threads):
            rec.add_topic(f'own{k}', WRENCH, {})

        def work(k):
            for i in range(per_thread):
                rec.write('shared', data, T0 + (k * per_thread + i) * 1000)
                rec.write(f'own{k}', data, T0 + i * 1000)
        threads = [threading.Thread(target=work, args=(k,)) for k in range(n_threads)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert rec.stats().messages_dropped == 0
    with open(path, 'rb') as f:
        reader = make_reader(f)
        stats = reader.get_summary().statistics
        seqs = {}
        for _, c, m in reader.iter_messages(log_time_order=False):
            seqs.setdefault(c.topic, []).append(m.sequence)
    assert stats.message_count == 2 * n_threads * per_thread
    assert sorted(seqs['shared']) == list(range(1, n_threads * per_thread + 1))
    assert all(sorted(seqs[f'own{k}']) == list(range(1, per_thread + 1)) for k in range(n_threads))
    assert stats.chunk_count > 10  # the size limit ended chunks while threads were writing


# -- chunks and hard kills ---------------------------------------------------------------------

def _snapshot(path, dst):
    """What a hard kill would leave now: the bytes the OS holds for the file."""
    shutil.copyfile(path, dst)
    return dst


class _WriterWithoutFlush:
    """A writer as mcap < 1.6 had it: no public flush()."""

    def __init__(self, writer):
        self._writer = writer

    def __getattr__(self, name):
        if name == 'flush':
            raise AttributeError(name)
        return getattr(self._writer, name)


@pytest.mark.parametrize('old_mcap', [False, True])
def test_end_chunk_makes_messages_readable(tmp_path, old_mcap):
    path = tmp_path / 'w.mcap'
    with open(path, 'wb') as f:
        writer = Writer(f, chunk_size=1 << 30)
        writer.start(profile='ros2')
        sid = writer.register_schema('x/msg/Y', 'ros2msg', b'int32 a')
        cid = writer.register_channel('t', 'cdr', sid)
        for i in range(3):
            writer.add_message(cid, T0 + i, b'\0\1\0\0' + bytes(4), T0 + i)
        f.flush()
        before = ml.recover_truncated(_snapshot(path, tmp_path / 'before.mcap'))
        ml.end_chunk(_WriterWithoutFlush(writer) if old_mcap else writer)
        f.flush()  # the fallback ends the chunk but leaves this buffered file to its owner
        after = ml.recover_truncated(_snapshot(path, tmp_path / 'after.mcap'))
        writer.finish()
    assert before['messages'] == 0  # the open chunk lives in memory only
    assert after['messages'] == 3 and not after['complete']
    assert ml.recover_truncated(path)['complete']


def test_chunks_end_every_interval_of_log_time(tmp_path):
    """Synthetic 50 Hz log time written at full speed: chunks end on log time alone."""
    path = tmp_path / 'interval.mcap'
    rec = ml.McapRecorder(path, metadata={'scene': 's'}, chunk_interval_s=1.0, background=False)
    rec.add_topic('needle/wrench', WRENCH, {})
    n = 176  # 3.5 s at 50 Hz
    for i in range(n):
        rec.write('needle/wrench', serialize_message(_sample('needle/wrench', i)), T0 + i * PERIOD)
    snap = _snapshot(path, tmp_path / 'killed.mcap')
    report = ml.recover_truncated(snap)
    assert not report['complete'] and report['error']
    # a chunk ends with the first message >= 0.5 s (half the interval) after its first:
    # 26 messages each, 6 chunks closed, 20 messages in the open one
    assert report['messages'] == 156
    assert report['first_log_time_ns'] == T0
    lost_s = (T0 + (n - 1) * PERIOD - report['last_log_time_ns']) / 1e9
    assert 0 < lost_s <= 0.5
    assert report['metadata']['tissue_sim']['scene'] == 's'
    with pytest.raises(ml.TruncatedLogError):
        list(ml.read_log(snap))
    recovered = list(ml.read_log(snap, allow_truncated=True))
    assert [m.log_time_ns for m in recovered] == [T0 + i * PERIOD for i in range(156)]
    assert ml.read_metadata(snap)['scene'] == 's'  # metadata survives: written first
    rec.close()
    assert ml.summarize_log(path)['statistics']['message_count'] == n


def test_background_writer_ends_an_idle_chunk_on_wall_time(tmp_path):
    path = tmp_path / 'idle.mcap'
    with ml.McapRecorder(path, metadata={}, chunk_interval_s=0.2) as rec:
        rec.add_topic('needle/wrench', WRENCH, {})
        for i in range(3):  # same log time: only the wall-clock rule can end this chunk
            rec.write('needle/wrench', serialize_message(_sample('needle/wrench', i)), T0)
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            time.sleep(0.05)
            if ml.recover_truncated(_snapshot(path, tmp_path / 'snap.mcap'))['messages'] == 3:
                break
        else:
            pytest.fail('the open chunk was not written within 5 s of wall time')
        assert rec.stats().chunks_closed == 1


def test_a_backlog_is_written_as_one_chunk_not_one_per_message(tmp_path):
    """Messages that waited in the queue longer than the chunk age (a stalled writer) go into
    the chunk together once the writer drains the queue, rather than closing a chunk each."""
    path = tmp_path / 'backlog.mcap'
    data = serialize_message(_sample('needle/wrench', 0))
    with ml.McapRecorder(path, metadata={}, chunk_interval_s=0.1) as rec:
        rec.add_topic('needle/wrench', WRENCH, {})
        with rec._lock:  # the writer thread waits: the queue fills
            for i in range(200):
                rec.write('needle/wrench', data, T0 + i * 1000)  # 1 us apart in log time
            time.sleep(0.3)  # every queued message is now older than the 0.05 s chunk age
        rec.flush()
        assert rec.stats().messages_written == 200
    with open(path, 'rb') as f:
        stats = make_reader(f).get_summary().statistics
    assert stats.message_count == 200 and stats.chunk_count <= 3


def test_the_writer_thread_wakes_per_batch_not_per_message(tmp_path):
    """A node writes at 50-100 Hz on several topics; the writer thread takes them in batches at
    most every 50 ms (chunk_interval_s / 10 when shorter) instead of waking for each message.
    400 messages 2.5 ms apart (1 s): about 1 s / 0.05 s wakes, every message written, in order."""
    path = tmp_path / 'batches.mcap'
    with ml.McapRecorder(path, metadata={}, chunk_interval_s=1.0) as rec:
        rec.add_topic('needle/wrench', WRENCH, {})
        start = time.monotonic()
        for i in range(400):
            rec.write('needle/wrench', serialize_message(_sample('needle/wrench', i)), T0 + i * PERIOD)
            time.sleep(max(0.0, start + (i + 1) * 0.0025 - time.monotonic()))
        elapsed = time.monotonic() - start
        rec.flush()
        stats = rec.stats()
    assert stats.messages_written == 400
    assert stats.writer_wakeups <= elapsed / 0.05 + 5, (stats.writer_wakeups, elapsed)
    assert [m.log_time_ns for m in ml.read_log(path)] == [T0 + i * PERIOD for i in range(400)]


_CHILD = textwrap.dedent('''
    import sys, time
    from rclpy.serialization import serialize_message
    from tissue_sim_ros.io import mcap as ml
    from tissue_sim_ros.ros.messages import conversions as cv
    path, mode = sys.argv[1], sys.argv[2]
    T0, PERIOD = {T0}, {PERIOD}
    rec = ml.McapRecorder(path, metadata={{'scene': 'kill test'}}, chunk_interval_s=1.0)
    rec.add_topic('needle/wrench', 'geometry_msgs/msg/WrenchStamped', {{}})
    start = time.monotonic()
    for i in range(10_000 if mode == 'kill' else 40):
        msg = cv.wrench_msg([float(i), 0.0, 0.0], [0.0, 0.0, 0.0], 'needle', T0 + i * PERIOD)
        rec.write('needle/wrench', serialize_message(msg), T0 + i * PERIOD)
        print(i, flush=True)
        if mode == 'kill':
            time.sleep(max(0.0, start + (i + 1) * PERIOD / 1e9 - time.monotonic()))
    # mode 'exit': no close(); the interpreter exits normally
''').format(T0=T0, PERIOD=PERIOD)


def _child(tmp_path, path, mode):
    script = tmp_path / 'child.py'
    script.write_text(_CHILD)
    env = dict(os.environ, PYTHONUNBUFFERED='1')
    return subprocess.Popen([sys.executable, str(script), str(path), mode], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_sigkill_loses_at_most_about_one_second(tmp_path):
    path = tmp_path / 'killed.mcap'
    proc = _child(tmp_path, path, 'kill')
    last = -1
    try:
        for line in proc.stdout:  # messages written at 50 Hz of wall and log time
            last = int(line)
            if last >= 135:  # 2.7 s: two chunks closed, the third open
                break
        proc.send_signal(signal.SIGKILL)
        rest, err = proc.communicate(timeout=10)
    finally:
        proc.kill()
    assert last >= 135, err
    last = max([last] + [int(x) for x in rest.split()])
    assert proc.returncode == -signal.SIGKILL
    report = ml.recover_truncated(path)
    assert not report['complete']
    recovered = [int(round(m.message.wrench.force.x))
                 for m in ml.read_log(path, allow_truncated=True)]
    assert recovered == list(range(len(recovered)))  # an intact prefix, nothing garbled
    lost = last + 1 - len(recovered)  # +1: a message may be written but not yet printed
    assert 0 <= lost <= 50 + 2, (last, len(recovered))  # at most 1 s of 50 Hz, and the queue
    assert len(recovered) >= 100
    assert report['metadata']['tissue_sim']['scene'] == 'kill test'
    with pytest.raises(Exception):  # a seeking reader refuses the torn file...
        with AnyReader([path]) as reader:
            list(reader.messages())
    repaired = ml.recover_truncated(path, repaired_path=tmp_path / 'repaired.mcap')
    with AnyReader([tmp_path / 'repaired.mcap']) as reader:  # ...and opens the repaired copy
        assert sum(c.msgcount for c in reader.connections) == len(recovered)
        assert reader.connections[0].ext.offered_qos_profiles  # QoS kept
    assert repaired['messages'] == len(recovered)
    assert ml.read_metadata(tmp_path / 'repaired.mcap')['scene'] == 'kill test'


def test_interpreter_exit_without_close_leaves_a_complete_file(tmp_path):
    path = tmp_path / 'exit.mcap'
    proc = _child(tmp_path, path, 'exit')
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    s = ml.summarize_log(path)  # raises on a torn file
    assert s['statistics']['message_count'] == s['message_count'] == 40


# -- the TypeScript reader (Foxglove / Lichtblick) ----------------------------------------------

_JS = r'''
import { readFileSync } from 'node:fs';
import { McapStreamReader, McapIndexedReader } from '@mcap/core';
import { decompress } from 'fzstd';
const handlers = { zstd: (buf, size) => decompress(buf, new Uint8Array(Number(size))) };
const results = {};
for (const file of process.argv.slice(2)) {
  const bytes = new Uint8Array(readFileSync(file));
  const out = { stream: {}, indexed: {} };
  try {
    const reader = new McapStreamReader({ validateCrcs: true, decompressHandlers: handlers });
    reader.append(bytes);
    const topics = new Map(); const counts = {}; const metadata = []; let profile = null;
    for (let r; (r = reader.nextRecord()); ) {
      if (r.type === 'Header') profile = r.profile;
      if (r.type === 'Channel') topics.set(r.id, r.topic);
      if (r.type === 'Metadata') metadata.push(r.name);
      if (r.type === 'Message') {
        const t = topics.get(r.channelId); counts[t] = (counts[t] ?? 0) + 1;
      }
    }
    Object.assign(out.stream, { profile, counts, metadata, done: reader.done() });
  } catch (e) { out.stream.error = String(e); }
  try {
    const readable = { size: async () => BigInt(bytes.length),
      read: async (offset, size) => bytes.subarray(Number(offset), Number(offset + size)) };
    const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers: handlers });
    const counts = {};
    for await (const m of reader.readMessages()) {
      const t = reader.channelsById.get(m.channelId).topic; counts[t] = (counts[t] ?? 0) + 1;
    }
    const metadata = {};
    for await (const m of reader.readMetadata()) metadata[m.name] = Object.fromEntries(m.metadata);
    Object.assign(out.indexed, { counts, metadata,
      statisticsMessageCount: Number(reader.statistics?.messageCount ?? -1),
      compression: [...new Set(reader.chunkIndexes.map((c) => c.compression))] });
  } catch (e) { out.indexed.error = String(e); }
  results[file] = out;
}
console.log(JSON.stringify(results));
'''


def test_typescript_reader_validates_the_file(recorded, mcap_js, tmp_path):
    path, written = recorded
    # a torn copy of a second file: cut in the middle of its last chunk (no summary)
    rec_path = tmp_path / 'chunks.mcap'
    with ml.McapRecorder(rec_path, metadata={'scene': 's'}, chunk_interval_s=0.1,
                         background=False) as rec:
        rec.add_topic('needle/wrench', WRENCH, {})
        for i in range(100):
            rec.write('needle/wrench', serialize_message(_sample('needle/wrench', i)),
                      T0 + i * PERIOD)
    with open(rec_path, 'rb') as f:
        last_chunk = make_reader(f).get_summary().chunk_indexes[-1]
    torn = tmp_path / 'torn.mcap'
    cut = last_chunk.chunk_start_offset + last_chunk.chunk_length // 2
    torn.write_bytes(rec_path.read_bytes()[:cut])
    results = mcap_js(path, rec_path, torn)
    good = results[str(path)]
    assert 'error' not in good['stream'] and 'error' not in good['indexed'], good
    assert good['stream']['done'] is True and good['stream']['profile'] == 'ros2'
    assert good['stream']['counts'] == good['indexed']['counts'] == {t: 5 for t in TOPICS}
    assert good['indexed']['statisticsMessageCount'] == len(written)
    assert good['indexed']['compression'] == ['zstd']
    assert good['indexed']['metadata']['tissue_sim']['package_version'] == \
        tissue_sim_ros.__version__
    assert results[str(rec_path)]['stream']['counts'] == {'needle/wrench': 100}
    bad = results[str(torn)]
    assert 'error' in bad['indexed']  # no footer: refused
    assert bad['stream'].get('done') is not True
    recovered = ml.recover_truncated(torn)['messages']
    assert 0 < recovered < 100
    assert bad['stream']['counts'] == {'needle/wrench': recovered}  # same intact chunks


@pytest.mark.parametrize('background', [False, True])
def test_a_hard_kill_loses_exactly_the_unsaved_messages(tmp_path, background):
    """At any moment the file holds every message but those the recorder reports unsaved.

    Small chunks (size limit) and a short interval: chunks end by size and by log time, and each
    ended chunk must be in the OS at once (no buffer of the writer holds it back).
    """
    path = tmp_path / 'unsaved.mcap'
    rng = np.random.default_rng(3)
    with ml.McapRecorder(path, metadata={}, chunk_size=8192, chunk_interval_s=0.5,
                         background=background) as rec:
        rec.add_topic('tissue/nodes', CLOUD, {})
        rec.add_topic('needle/wrench', WRENCH, {})
        cloud = serialize_message(_sample('tissue/nodes', 0))  # about 1 kB
        wrench = serialize_message(_sample('needle/wrench', 0))
        checks = 0
        for i in range(400):
            rec.write('needle/wrench', wrench, T0 + i * PERIOD)
            if i % 3 == 0:
                rec.write('tissue/nodes', cloud, T0 + i * PERIOD)
            if rng.random() < 0.06:
                if background:
                    rec._queue.join()  # a quiet moment, so the snapshot is consistent
                st = rec.stats()
                snap = _snapshot(path, tmp_path / f'snap{i}.mcap')
                got = ml.recover_truncated(snap)['messages']
                assert got == st.messages_written - st.messages_unsaved, (i, st)
                assert st.messages_unsaved < 60  # 0.5 s of log time or 8 kB
                checks += 1
        assert checks >= 10 and rec.stats().chunks_closed > 20


def test_complete_file_passes_a_crc_checked_stream_read(recorded):
    path, written = recorded
    report = ml.recover_truncated(path)  # chunk CRCs and the data-section CRC are checked
    assert report['complete'] and report['error'] is None
    assert report['messages'] == len(written)
    with open(path, 'rb') as f:
        data_end = [r for r in StreamReader(f, validate_crcs=True).records
                    if type(r).__name__ == 'DataEnd']
    assert len(data_end) == 1 and data_end[0].data_section_crc != 0


def test_writer_thread_errors_reach_the_caller(tmp_path):
    rec = ml.McapRecorder(tmp_path / 'err.mcap', metadata={})
    rec.add_topic('needle/wrench', WRENCH, {})

    def disk_full(data):
        raise OSError(28, 'No space left on device')
    rec._sink.write = disk_full  # the next chunk end fails in the writer thread
    rec.write('needle/wrench', serialize_message(_sample('needle/wrench', 0)), T0)
    with pytest.raises(RuntimeError, match='No space left'):
        rec.flush()
    with pytest.raises(RuntimeError, match='No space left'):
        rec.write('needle/wrench', serialize_message(_sample('needle/wrench', 1)), T0)
    with pytest.raises(RuntimeError, match='No space left'):
        rec.close()
    rec.close()  # once reported, closing again is quiet
    assert rec.closed
