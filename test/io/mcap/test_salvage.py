"""A damaged log gives back every readable chunk, before and after the damage, and says exactly
what was lost where (io.mcap.salvage, io.mcap.recovery). Truth: the messages the test wrote,
read back from the original with the mcap library and from the repaired copy with rosbags."""
import pytest

pytest.importorskip('rclpy')
from mcap.reader import make_reader  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from rosbags.highlevel import AnyReader  # noqa: E402

from tissue_sim_ros.cli import main  # noqa: E402
from tissue_sim_ros.io import mcap as ml  # noqa: E402
from tissue_sim_ros.io.mcap.recovery import recover_log  # noqa: E402
from tissue_sim_ros.ros.messages import conversions as cv  # noqa: E402

T0 = 1_700_000_000_000_000_000
PERIOD = 20_000_000


@pytest.fixture(scope='module')
def chunked_log(tmp_path_factory):
    """A closed log of 300 wrenches and 100 poses in chunks of 0.2 s of log time."""
    from geometry_msgs.msg import PoseStamped
    path = tmp_path_factory.mktemp('salvage') / 'run.mcap'
    with ml.McapRecorder(path, metadata={'scene': 'kept'}, chunk_interval_s=0.2, background=False) as rec:
        rec.add_topic('needle/wrench', 'geometry_msgs/msg/WrenchStamped', {'depth': 10})
        rec.add_topic('needle/pose', 'geometry_msgs/msg/PoseStamped', None)
        for i in range(300):
            t = T0 + i * PERIOD
            rec.write('needle/wrench', serialize_message(cv.wrench_msg([i, 0, 0], [0, 0, 0], 'needle', t)), t)
            if i % 3 == 0:
                pose = PoseStamped()
                pose.header.stamp = cv.ns_to_stamp(t)
                pose.pose.position.x = 1e-3 * i
                pose.pose.orientation.w = 1.0
                rec.write('needle/pose', serialize_message(pose), t + 5)
    return path


def _chunks(path):
    """[(start, end, first log time, last log time)] of the file's chunks, from its own index."""
    with open(path, 'rb') as f:
        return [(i.chunk_start_offset, i.chunk_start_offset + i.chunk_length, i.message_start_time,
                 i.message_end_time) for i in make_reader(f).get_summary().chunk_indexes]


def _messages(path):
    """(topic, log time, payload) of every message, in file order (the mcap library)."""
    with open(path, 'rb') as f:
        return [(c.topic, m.log_time, bytes(m.data)) for _, c, m in make_reader(f).iter_messages(log_time_order=False)]


def _repaired(path):
    with AnyReader([path]) as reader:
        return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]


def _damaged_copy(source, target, offset, length=8):
    body = bytearray(source.read_bytes())
    body[offset:offset + length] = bytes(b ^ 0xFF for b in body[offset:offset + length])
    target.write_bytes(bytes(body))


@pytest.mark.parametrize('summary', ['kept', 'cut off'])
def test_a_damaged_chunk_loses_only_its_own_messages(chunked_log, tmp_path, summary):
    """8 bytes flipped inside a middle chunk: that chunk's messages are lost, every other chunk's
    are kept (counted against the original), and the report says where and what. With the
    summary cut off the next chunk is found by scanning."""
    chunks = _chunks(chunked_log)
    assert len(chunks) >= 10
    k = len(chunks) // 2
    start, end, first, last = chunks[k]
    original = _messages(chunked_log)
    lost = [m for m in original if first <= m[1] <= last]
    damaged = tmp_path / 'damaged.mcap'
    _damaged_copy(chunked_log, damaged, (start + end) // 2)
    if summary == 'cut off':
        damaged.write_bytes(damaged.read_bytes()[:chunks[-1][1]])      # the data section's end and summary gone
    out = tmp_path / 'repaired.mcap'
    report, line = recover_log(damaged, out)
    assert _repaired(out) == sorted((m for m in original if m not in lost), key=lambda m: m[1])
    assert report['messages'] == len(original) - len(lost) and not report['complete']
    inside = [d for d in report['damage'] if d['end'] != report['file_bytes']]
    assert len(inside) == 1 and inside[0]['start'] == start and inside[0]['end'] >= end
    if summary == 'kept':                      # the indexes say exactly what the chunk held
        counts = {t: sum(1 for m in lost if m[0] == t) for t in {m[0] for m in lost}}
        assert inside[0]['messages'] == counts and report['lost_messages'] == len(lost)
        assert (inside[0]['first_log_time_ns'], inside[0]['last_log_time_ns']) == (first, last)
    assert f'bytes {start}-' in line and 'every readable chunk after it kept' in line
    assert ml.read_metadata(out)['scene'] == 'kept'


def test_a_damaged_chunk_header_is_skipped_too(chunked_log, tmp_path):
    """The damage on the chunk's own length field: the walk cannot step over it and resumes at
    the next chunk the index names."""
    start, end, first, last = _chunks(chunked_log)[3]
    damaged = tmp_path / 'header.mcap'
    _damaged_copy(chunked_log, damaged, start + 1)
    report = ml.recover_truncated(damaged)
    original = _messages(chunked_log)
    assert report['messages'] == len([m for m in original if not first <= m[1] <= last])


def test_a_complete_log_is_complete_and_a_tiny_file_is_explained(chunked_log, tmp_path, capsys):
    report = ml.recover_truncated(chunked_log)
    assert report['complete'] and report['damage'] == [] and report['lost_messages'] == 0
    tiny = tmp_path / 'tiny.mcap'
    tiny.write_bytes(chunked_log.read_bytes()[:20])
    assert main(['recover', str(tiny), '--out', str(tmp_path / 'tiny_out.mcap')]) == 0
    line = capsys.readouterr().out
    assert 'kept 0 messages' in line and 'Invalid argument' not in line
