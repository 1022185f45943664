"""Logs cut short (io/mcap/recovery.py): the CRC-checked stream read of a complete file, and
tissue-sim recover on a log cut at many places. Truth: the mcap library's records and rosbags."""

import subprocess
import sys

import pytest

pytest.importorskip('rclpy')

from mcap.data_stream import ReadDataStream  # noqa: E402
from mcap.reader import make_reader  # noqa: E402
from mcap.records import Chunk  # noqa: E402
from mcap.stream_reader import StreamReader, breakup_chunk  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from rosbags.highlevel import AnyReader  # noqa: E402

from support.bad_payloads import _pose  # noqa: E402
from support.mcap_samples import PERIOD, POSE, T0, WRENCH  # noqa: E402
from tissue_sim_ros.cli import app as cli  # noqa: E402
from tissue_sim_ros.io import mcap as ml  # noqa: E402
from tissue_sim_ros.ros.messages import conversions as cv  # noqa: E402
from tissue_sim_ros.units import NS_PER_S  # noqa: E402


def test_complete_file_passes_a_crc_checked_stream_read(recorded):
    path, written = recorded
    report = ml.recover_truncated(path)  # chunk CRCs and the data-section CRC are checked
    assert report['complete'] and report['error'] is None
    assert report['messages'] == len(written)
    with open(path, 'rb') as f:
        data_end = [r for r in StreamReader(f, validate_crcs=True).records
                    if type(r).__name__ == 'DataEnd']
    assert len(data_end) == 1 and data_end[0].data_section_crc != 0


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
