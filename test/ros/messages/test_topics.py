"""The node's topics in one place (ros/messages/topics.py): every type named is a real ROS type,
and each profile is the QoS its docstring states. Truth: the generated message classes' own type
names, rclpy's policy enums."""
import pytest

pytest.importorskip('rclpy')

from rclpy.qos import DurabilityPolicy, HistoryPolicy, ReliabilityPolicy  # noqa: E402

from tissue_sim_ros.ros.messages import topics  # noqa: E402
from tissue_sim_ros.ros.messages.from_yaml import message_type  # noqa: E402


def test_every_topic_type_is_a_message_class_of_that_name():
    for topic, type_name in topics.NODE_TOPIC_TYPES.items():
        cls = message_type(type_name)
        package, _, name = type_name.split('/')
        assert (cls.__module__.split('.')[0], cls.__name__) == (package, name), topic


@pytest.mark.parametrize('profile, depth, reliable, latched', [
    (topics.WRENCH_QOS, 10, True, False), (topics.NODES_QOS, 2, True, False),
    (topics.SURFACE_QOS, 1, True, True), (topics.MARKER_QOS, 1, True, False),
    (topics.PLAN_QOS, 100, True, False), (topics.pose_qos('reliable'), 100, True, False),
    (topics.pose_qos('best_effort'), 100, False, False),
])
def test_each_profile_keeps_its_depth_with_the_stated_reliability_and_durability(profile, depth, reliable, latched):
    assert profile.history == HistoryPolicy.KEEP_LAST and profile.depth == depth
    assert profile.reliability == (ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT)
    assert profile.durability == (DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


def test_one_needle_keeps_todays_topics_and_several_get_their_own():
    assert topics.needle_topics(['needle']) == [('needle/pose', 'needle/wrench')]
    assert topics.needle_topics(['a', 'b']) == [('needle/a/pose', 'needle/a/wrench'),
                                                ('needle/b/pose', 'needle/b/wrench')]
