"""Reading logs back (io/mcap/reader.py): the round trip, the summary, and undecodable messages
skipped and reported. Truth: what the test wrote and rosbags' own decoder."""

import pytest

pytest.importorskip('rclpy')

from mcap.reader import make_reader  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from support.bad_payloads import _bad_payloads, _pose  # noqa: E402
from support.mcap_samples import POSE, TOPICS, _check_values  # noqa: E402
from tissue_sim_ros.io import mcap as ml  # noqa: E402


def test_bad_payloads_are_refused_by_an_independent_decoder():
    """The premise: rosbags refuses every bad payload and decodes the good pose."""
    store = get_typestore(Stores.ROS2_JAZZY)
    assert store.deserialize_cdr(serialize_message(_pose(3)), POSE).pose.position.x == 0.003
    for name, payload in _bad_payloads().items():
        with pytest.raises(Exception):
            store.deserialize_cdr(payload, POSE)
            pytest.fail(f'rosbags decoded the {name} payload')


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


def test_round_trip_with_read_log(recorded):
    path, written = recorded
    got = list(ml.read_log(path))
    assert [(m.topic, m.type_name, m.log_time_ns) for m in got] == \
        [(t, ty, lt) for t, ty, lt, _, _ in written]  # written in log-time order
    for (topic, _, _, _, i), m in zip(written, got):
        _check_values(topic, m.message, i)
    only = list(ml.read_log(path, topics=['needle/wrench']))
    assert len(only) == 5 and {m.topic for m in only} == {'needle/wrench'}


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
