"""The names of the MCAP ``ros2`` profile (io/mcap/profile.py) in the files this package writes:
the header's profile and library, the encodings of schemas and channels. Truth: the mcap
library's reader, and the installed package's version from importlib.metadata."""
import importlib.metadata

from mcap.reader import make_reader

from tissue_sim_ros.io.mcap import McapRecorder, recover_truncated


def _header_and_summary(path):
    with open(path, 'rb') as f:
        reader = make_reader(f)
        return reader.get_header(), reader.get_summary()


def test_a_log_and_its_repaired_copy_name_the_profile_and_this_package(tmp_path):
    version = importlib.metadata.version('tissue_sim_ros')
    path = tmp_path / 'run.mcap'
    with McapRecorder(path, metadata={'scene': 's'}) as recorder:
        recorder.add_topic('count', 'std_msgs/msg/UInt8', {})
        for i in range(3):
            recorder.write('count', bytes([0, 1, 0, 0, i]), 1000 + i)
    header, summary = _header_and_summary(path)
    assert header.profile == 'ros2' and header.library.startswith(f'tissue_sim_ros/{version} ')
    assert {s.encoding for s in summary.schemas.values()} == {'ros2msg'}
    assert {c.message_encoding for c in summary.channels.values()} == {'cdr'}
    torn = tmp_path / 'torn.mcap'
    torn.write_bytes(path.read_bytes()[:-40])                 # the footer gone
    recover_truncated(torn, repaired_path=tmp_path / 'repaired.mcap')
    header, summary = _header_and_summary(tmp_path / 'repaired.mcap')
    assert header.profile == 'ros2' and header.library == f'tissue_sim_ros/{version} recover'
    assert summary.statistics.message_count == 3
