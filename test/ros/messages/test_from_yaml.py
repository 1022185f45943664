"""msg_examples/: every file converts into its real message type and says what the node does."""

import os

import numpy as np
import pytest
import yaml

rclpy = pytest.importorskip('rclpy')

from rclpy.parameter import Parameter  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402

from support.paths import ROOT  # noqa: E402
from tissue_sim_ros.ros.messages import conversions as cv  # noqa: E402
from tissue_sim_ros.ros.messages.from_yaml import load_example, message_from_dict, message_type  # noqa: E402

EXAMPLES = sorted((ROOT / 'msg_examples').glob('*.yaml'))


def test_there_are_examples():
    assert len(EXAMPLES) == 18


@pytest.mark.parametrize('path', EXAMPLES, ids=lambda p: p.name)
def test_example_converts_into_its_type_and_survives_serialization(path):
    example = load_example(path)
    for role, msg in example['messages'].items():
        cls = type(msg)
        back = deserialize_message(serialize_message(msg), cls)  # float32 fields round once
        assert deserialize_message(serialize_message(back), cls) == back, role
        if role == 'message':
            assert cls is message_type(example['type'])
    assert sum(key in example for key in ('topic', 'service', 'action')) == 1


def _by_name(name):
    return load_example(ROOT / 'msg_examples' / name)


@pytest.fixture(scope='module')
def node_facts(tmp_path_factory):
    """What a real node declares: its topics, services and diagnostics keys."""
    from tissue_sim_ros.engine.scene.scene import Scene
    from tissue_sim_ros.ros.node import TissueSimNode
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=90 + os.getpid() % 20)
    scene = Scene.from_file(None, mesh={'generator': 'box', 'divisions': [4, 4, 3]},
                            targets=[{'name': 'tumour', 'position_m': [0.002, 0.0, -0.015]}])
    node = TissueSimNode(scene=scene, context=ctx, parameter_overrides=[Parameter(
        'recording.directory', value=str(tmp_path_factory.mktemp('ex'))), Parameter('prediction.prestart', value=False)])
    try:
        ns = node.get_fully_qualified_name()
        facts = {
            'published': {p.topic_name for p in node.publishers} - {'/rosout', '/parameter_events'},
            'subscribed': {s.topic_name for s in node.subscriptions},
            'services': {node.resolve_service_name(s.srv_name) for s in node.services
                         if not any(w in s.srv_name for w in ('parameter', 'type_description'))},
            'diagnostics': {name: list(values) for name, _, _, values in
                            node.diagnostics_statuses(node.get_clock().now().nanoseconds)},
            'namespace': ns,
            'actions': {node.action_server.name},
            'wrench_frame_id': node.config.wrench_frame_id,
            'frame_id': node.config.frame_id,
        }
    finally:
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    return facts


def test_examples_cover_every_topic_and_service_of_the_node(node_facts):
    topics, services, actions = set(), set(), set()
    for path in EXAMPLES:
        doc = yaml.safe_load(path.read_text())
        if 'topic' in doc:
            name = doc['topic'].replace('~', node_facts['namespace'])
            topics.add(name if name.startswith('/') else '/' + name)
        elif 'service' in doc:
            services.add(doc['service'].replace('~', node_facts['namespace']))
        else:
            actions.add(doc['action'].replace('~', node_facts['namespace']))
    assert topics == node_facts['published'] | node_facts['subscribed']
    assert services == node_facts['services']
    assert actions == node_facts['actions']


def test_diagnostics_example_has_the_nodes_keys(node_facts):
    msg = _by_name('diagnostics.yaml')['messages']['message']
    example = {st.name: [kv.key for kv in st.values] for st in msg.status}
    assert example == node_facts['diagnostics']


def test_frames_match_the_node_defaults(node_facts):
    assert _by_name('needle_wrench.yaml')['messages']['message'].header.frame_id == \
        node_facts['wrench_frame_id']
    assert _by_name('needle_pose.yaml')['messages']['message'].header.frame_id == \
        node_facts['frame_id']


def test_pose_example_is_the_default_scenes_initial_pose():
    scene = yaml.safe_load((ROOT / 'config' / 'liver_sample.yaml').read_text())
    pose = _by_name('needle_pose.yaml')['messages']['message'].pose
    p, q = pose.position, pose.orientation
    assert [p.x, p.y, p.z] == scene['needle']['initial_position_m']
    assert [q.x, q.y, q.z, q.w] == scene['needle']['initial_orientation_xyzw']


def test_point_cloud_example_decodes_to_the_values_it_states():
    msg = _by_name('tissue_nodes.yaml')['messages']['message']
    positions, displacement = cv.point_cloud_arrays(msg)
    np.testing.assert_allclose(positions, [[0, 0, -0.0021], [0.00152, 0, -0.0017]], atol=1e-9)
    np.testing.assert_allclose(displacement, [[0, 0, -0.0021], [2e-5, 0, -0.0013]], atol=1e-9)
    assert len(msg.data) == msg.row_step == msg.width * msg.point_step


def test_mesh_and_marker_examples_are_consistent():
    mesh = _by_name('tissue_surface.yaml')['messages']['message']
    assert max(max(t.vertex_indices) for t in mesh.triangles) < len(mesh.vertices)
    marker = _by_name('tissue_marker.yaml')['messages']['message']
    assert marker.type == marker.TRIANGLE_LIST and len(marker.points) % 3 == 0


def test_bad_example_fields_are_refused_with_their_path():
    from geometry_msgs.msg import PoseStamped
    with pytest.raises(ValueError, match=r'pose\.position: unknown fields \[.w.\]'):
        message_from_dict(PoseStamped, {'pose': {'position': {'w': 1.0}}})
    with pytest.raises(ValueError, match=r'header\.frame_id'):
        message_from_dict(PoseStamped, {'header': {'frame_id': 3}})
