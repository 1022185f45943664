"""ROS type names and ``ros2msg`` schema text (io/mcap/message_definitions.py), read back by
rosbags' own parser."""

import pytest

pytest.importorskip('rclpy')

from rclpy.serialization import serialize_message  # noqa: E402
from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402

from support.mcap_samples import DIAG, MARKER, POSE, WRENCH, _check_values, _sample  # noqa: E402
from tissue_sim_ros.io import mcap as ml  # noqa: E402


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
