"""MCAP recording (io/mcap/writer.py), checked with readers this project did not write.

Independent readers: ``rosbags`` (AnyReader on the bare .mcap, its own .msg parser and CDR
decoder), the ``mcap`` package's reader (records, summary, metadata), and, where Node.js and npm
are present, the TypeScript ``@mcap/core`` reader used by Foxglove/Lichtblick, with CRC checks."""

import os
import re
import signal
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest

pytest.importorskip('rclpy')

from mcap.reader import make_reader  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from rosbags.highlevel import AnyReader  # noqa: E402

from support.mcap_samples import (CLOUD, PERIOD, POSE, T0, TOPICS, WRENCH, _check_values, _sample,
                                  _snapshot)  # noqa: E402
from tissue_sim_ros.io import mcap as ml  # noqa: E402
import tissue_sim_ros  # noqa: E402


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


def test_bad_payloads_are_recorded_verbatim(log_with_bad_poses):
    path, good_times, bad_times, bad = log_with_bad_poses
    with open(path, 'rb') as f:
        pose_payloads = {m.log_time: m.data for _, c, m in make_reader(f).iter_messages()
                         if c.topic == 'needle/pose'}
    assert [pose_payloads[t] for t in bad_times] == [payload for _, payload in bad]
    with AnyReader([path]) as reader:  # the file itself is sound: rosbags opens it
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts == {'needle/pose': len(good_times) + len(bad_times), 'needle/wrench': 30}
