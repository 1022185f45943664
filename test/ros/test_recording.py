"""What the node records (ros/recording.py): every message in and out, the cloud at its own rate,
an unwritable directory refused, and after a hard kill at most the open chunk lost."""

import math
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

rclpy = pytest.importorskip('rclpy')

from rclpy.parameter import Parameter  # noqa: E402
from rclpy.serialization import deserialize_message  # noqa: E402
from std_srvs.srv import SetBool  # noqa: E402

from support.node_process import Client, _DOMAINS, start_node  # noqa: E402
from support.ros_clients import DOMAIN_ID  # noqa: E402
from support.ros_harness import publish_at_stamps, shared_scene, straight_descent  # noqa: E402
from tissue_sim_ros.io import mcap as ml  # noqa: E402
from tissue_sim_ros.ros import node as node_mod  # noqa: E402
from tissue_sim_ros.ros.messages import conversions as cv  # noqa: E402


def test_unwritable_recording_directory_is_refused(tmp_path):
    blocker = tmp_path / 'a_file'
    blocker.write_text('')
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=DOMAIN_ID)
    try:
        with pytest.raises(node_mod.ConfigError, match='recording.directory'):
            node_mod.TissueSimNode(scene=shared_scene(), context=ctx, parameter_overrides=[
                Parameter('recording.directory', value=str(blocker / 'sub'))])
    finally:
        rclpy.shutdown(context=ctx)


def test_recording_holds_every_message_in_and_out(harness, tmp_path):
    from rosbags.highlevel import AnyReader
    from tissue_sim_ros.io import mcap as ml
    h = harness(**{'recording.directory': str(tmp_path), 'recording.chunk_interval_s': 0.2,
                   'recording.nodes_rate_hz': 50.0})
    path = h.node.recording_path
    start = h.scene.needle_pose[0]
    stamps, positions = straight_descent(start, 0.02, 1.0, 100.0, h.now_ns())
    publish_at_stamps(h, stamps, positions)
    h.publish_pose([np.nan, 0, 0], h.now_ns(), kind='non_finite')  # bad input is recorded too
    h.wait_until(lambda: h.node.input.received, lambda n: n >= len(h.published), what='every pose received')
    pause = h.call(h.pause_client, SetBool.Request(data=True))   # service calls are recorded too
    h.call(h.pause_client, SetBool.Request(data=False))
    h.node.publish_diagnostics()
    h.stop_node()
    received = {k: h.get(k) for k in ('wrench', 'nodes', 'surface', 'marker', 'diag')}
    # the node ticks before the client has discovered it: count from the first message received
    first = {k: cv.stamp_to_ns(received[k][0][1].header.stamp)
             for k in ('wrench', 'nodes', 'marker', 'diag')}
    expected = {'/needle/wrench': len(received['wrench']), '/tissue/nodes': len(received['nodes']),
                '/tissue/surface': len(received['surface']),
                '/tissue/marker': len(received['marker']),
                '/diagnostics': len(received['diag']), '/needle/pose': len(h.published),
                '/needle/shape': len(received['wrench'])}     # a shape with each tick's wrench
    key_of = {'/needle/wrench': 'wrench', '/tissue/nodes': 'nodes', '/tissue/marker': 'marker',
              '/diagnostics': 'diag', '/needle/shape': 'wrench'}
    types = {'/needle/wrench': 'geometry_msgs/msg/WrenchStamped',
             '/tissue/nodes': 'sensor_msgs/msg/PointCloud2', '/tissue/surface': 'shape_msgs/msg/Mesh',
             '/tissue/marker': 'visualization_msgs/msg/Marker',
             '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray',
             '/needle/pose': 'geometry_msgs/msg/PoseStamped', '/needle/shape': 'nav_msgs/msg/Path',
             '/tissue_sim/reset/_service_event': 'std_srvs/srv/Trigger_Event',
             '/tissue_sim/pause/_service_event': 'std_srvs/srv/SetBool_Event',
             '/tissue_sim/engine_trace': 'std_msgs/msg/Float64MultiArray',
             '/tissue_sim/set_tissue_pose/_service_event': 'tissue_sim_msgs/srv/SetTissuePose_Event',
             '/tissue_sim/register_needle/_service_event': 'std_srvs/srv/Trigger_Event',
             '/tf': 'tf2_msgs/msg/TFMessage', '/tf_static': 'tf2_msgs/msg/TFMessage',
             '/tissue_sim/ready': 'std_msgs/msg/Bool'}      # TF and readiness: test/ros/test_tf_out.py
    with AnyReader([path]) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == types
        raw_events = [raw for _, _, raw in reader.messages(
            connections=[c for c in reader.connections if c.topic == '/tissue_sim/pause/_service_event'])]
        # rosbags 0.11 files a 'pkg/srv/Type' schema under 'pkg/srv/msg/Type': its decoding of our
        # schema text must agree with rclpy's of the type itself
        events = [deserialize_message(raw, SetBool.Event) for raw in raw_events]
        decoded = [reader.typestore.deserialize_cdr(raw, 'std_srvs/srv/msg/SetBool_Event') for raw in raw_events]
        assert [(e.info.sequence_number, [r.data for r in e.request], [r.message for r in e.response])
                for e in decoded] == [(e.info.sequence_number, [r.data for r in e.request],
                                       [r.message for r in e.response]) for e in events]
        # request received, response sent; for each of the two calls
        assert [e.info.event_type for e in events] == [1, 2, 1, 2]
        assert [e.info.sequence_number for e in events] == [1, 1, 2, 2]
        assert [r.data for e in events for r in e.request] == [True, False]
        assert events[1].response[0].message == pause.message and events[1].response[0].success
        counts = {}
        traces = sum(1 for c in reader.connections if c.topic == '/tissue_sim/engine_trace'
                     for _ in reader.messages(connections=[c]))
        ticks = sum(1 for c in reader.connections if c.topic == '/needle/wrench'
                    for _ in reader.messages(connections=[c]))
        assert traces == ticks     # one engine trace per tick (replay)
        for c in reader.connections:
            if c.topic.endswith('/_service_event') or c.topic.endswith('/engine_trace') or \
                    c.topic in ('/tf', '/tf_static', '/tissue_sim/ready'):
                continue
            msgs = [reader.deserialize(raw, c.msgtype) for _, _, raw in
                    reader.messages(connections=[c])]
            if c.topic in key_of:
                msgs = [m for m in msgs if cv.stamp_to_ns(m.header.stamp) >= first[key_of[c.topic]]]
            counts[c.topic] = len(msgs)
        assert counts == expected
        wrench_conn = [c for c in reader.connections if c.topic == '/needle/wrench']
        recorded = [reader.deserialize(raw, c.msgtype) for c, _, raw in
                    reader.messages(connections=wrench_conn)]
        pose_conn = [c for c in reader.connections if c.topic == '/needle/pose']
        poses = [reader.deserialize(raw, c.msgtype) for c, _, raw in
                 reader.messages(connections=pose_conn)]
    got = [(cv.stamp_to_ns(w.header.stamp), w.wrench.force.z) for w in recorded]
    sent = [(cv.stamp_to_ns(w.header.stamp), w.wrench.force.z) for _, w in received['wrench']]
    assert got == sent
    assert [p.pose.position.z for p in poses][:len(stamps)] == positions[:, 2].tolist()
    assert math.isnan(poses[-1].pose.position.x)  # recorded as received
    meta = ml.read_metadata(path)
    assert meta['scene'] == h.scene.text
    params = yaml.safe_load(meta['parameters'])['tissue_sim']['ros__parameters']
    assert params['recording']['chunk_interval_s'] == 0.2 and params['publish_rate_hz'] == 50.0
    import tissue_sim_ros
    assert meta['package_version'] == tissue_sim_ros.__version__
    qos = ml.summarize_log(path)['topics']['/tissue/surface']['qos'][0]
    assert qos['durability'] == 'transient_local' and qos['reliability'] == 'reliable'


def test_the_cloud_is_recorded_at_its_own_rate(harness, tmp_path):
    """tissue/nodes is most of a log's bytes: recorded every k-th tick (recording.nodes_rate_hz)
    while it is published every tick."""
    from tissue_sim_ros.io import mcap as ml
    h = harness(**{'recording.directory': str(tmp_path), 'recording.nodes_rate_hz': 10.0})
    h.wait_for('nodes', 60)
    h.node.close()
    ticks = h.node.ticks
    recorded = sum(1 for _ in ml.read_log(h.node.recording_path, topics=['/tissue/nodes']))
    wrenches = sum(1 for _ in ml.read_log(h.node.recording_path, topics=['/needle/wrench']))
    assert wrenches == ticks and len(h.get('nodes')) >= 60
    assert recorded == -(-ticks // 5)  # ticks 0, 5, 10, ...


def _children(pid):
    tasks = Path(f'/proc/{pid}/task')
    return sorted({int(c) for task in tasks.iterdir() for c in (task / 'children').read_text().split()})


def _cmdline(pid):
    try:
        return Path(f'/proc/{pid}/cmdline').read_bytes().decode(errors='replace')
    except OSError:
        return ''


def test_sigkill_loses_at_most_the_open_chunk(tmp_path, scene_file):
    """After a hard kill the log has no summary, but every chunk closed so far is intact: with
    recording.chunk_interval_s = 0.5 at most about that much is lost (plus the writer queue)."""
    domain = next(_DOMAINS)
    proc = start_node(tmp_path, domain, scene_file, f'recording.directory:={tmp_path / "logs"}',
                      'recording.chunk_interval_s:=0.5')
    client = Client(domain)
    try:
        client.wait_ready(proc)
        client.wait_for('wrench', 0, 150, timeout=20.0)   # 3 s of ticks: chunks closed on the way
        client.wait_until(lambda: _children(proc.pid),
                          lambda pids: any('spawn_main' in _cmdline(pid) for pid in pids),
                          what='the prediction workers')
        children = _children(proc.pid)        # the prediction workers (prediction.prestart)
        assert any('spawn_main' in _cmdline(pid) for pid in children), children
        proc.kill()
        proc.wait(timeout=10)
        killed_at = time.monotonic()
        time.sleep(0.3)
        received = client.get('wrench')
        deadline = time.monotonic() + 5.0     # the workers see their node gone within a second
        while any(Path(f'/proc/{pid}').exists() and 'spawn_main' in _cmdline(pid) for pid in children):
            assert time.monotonic() < deadline, f'prediction workers {children} outlived the killed node'
            time.sleep(0.1)
    finally:
        if proc.poll() is None:
            proc.kill()
        client.close()
    (path,) = sorted((tmp_path / 'logs').glob('*.mcap'))
    with pytest.raises(ml.TruncatedLogError):
        ml.summarize_log(path)
    report = ml.recover_truncated(path, repaired_path=tmp_path / 'repaired.mcap')
    assert not report['complete']
    recovered = report['per_topic']['/needle/wrench']
    stamps = {cv.stamp_to_ns(m.message.header.stamp) for m in
              ml.read_log(path, topics=['/needle/wrench'], allow_truncated=True)}
    assert len(stamps) == recovered
    # every wrench received here more than a second before the kill is in the log
    older = {cv.stamp_to_ns(w.header.stamp) for t, w in received if t < killed_at - 1.0}
    assert len(older) > 50 and older <= stamps
    lost = {cv.stamp_to_ns(w.header.stamp) for _, w in received} - stamps
    assert len(lost) <= 55  # about the last second at 50 Hz, at most
    assert ml.read_metadata(path)['package_version']  # written first: survives
    from rosbags.highlevel import AnyReader
    with AnyReader([tmp_path / 'repaired.mcap']) as reader:
        assert {c.topic: c.msgcount for c in reader.connections}['/needle/wrench'] == recovered
