"""Log names and chunk ends (io/mcap/sink.py): new names never overwrite, and an ended chunk is
readable at once."""

import datetime as dt

import pytest

pytest.importorskip('rclpy')

from mcap.writer import Writer  # noqa: E402

from support.mcap_samples import T0, _snapshot  # noqa: E402
from tissue_sim_ros.io import mcap as ml  # noqa: E402


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
