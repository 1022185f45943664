"""The node as a child process (ros/clients/node_process.py): a refusal reaches the user with the
node's reason; a start is waited for on the node's latched ~/ready."""

import os
import time

import pytest


def test_a_node_that_refuses_its_parameters_is_one_error_naming_the_reason(tmp_path):
    pytest.importorskip('rclpy')
    from tissue_sim_ros.ros.clients.node_process import NodeProcess
    from tissue_sim_ros.errors import NodeProcessError
    with NodeProcess(['publish_rate_hz:=-5.0'], tmp_path / 'node.log') as node:
        assert node.env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
        assert node.env['ROS_DOMAIN_ID'] == str(node.domain_id) != os.environ.get('ROS_DOMAIN_ID')
        with pytest.raises(NodeProcessError) as refused:
            node.wait_until(lambda: False, timeout_s=120)
    message = str(refused.value)
    assert 'exited with status 2' in message and 'publish_rate_hz' in message
    assert str(tmp_path / 'node.log') in message and '\n' not in message


def test_the_console_script_node_says_ready_and_serves_the_registration(tmp_path):
    """tissue_sim_node as a child process (its own interpreter imports the built interfaces):
    NodeProcess waits on ~/ready, then ~/set_tissue_pose answers and /tf_static carries it."""
    rclpy = pytest.importorskip('rclpy')
    pytest.importorskip('tissue_sim_msgs.srv')
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from tf2_msgs.msg import TFMessage
    from tissue_sim_msgs.srv import SetTissuePose

    from tissue_sim_ros.ros.clients.node_process import NodeProcess, client_context

    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    with NodeProcess(['prediction.workers:=-1', 'registration.parent_frame_id:=base_link'],
                     tmp_path / 'node.log') as process:
        started = process.wait_until_ready(timeout_s=180)
        with client_context(process.domain_id) as context:
            client = rclpy.create_node('registrar', context=context)
            statics = []
            client.create_subscription(TFMessage, '/tf_static', statics.append, latched)
            service = client.create_client(SetTissuePose, '/tissue_sim/set_tissue_pose')
            executor = SingleThreadedExecutor(context=context)
            executor.add_node(client)
            assert service.wait_for_service(timeout_sec=10)
            request = SetTissuePose.Request()
            request.pose.pose.position.x, request.pose.pose.orientation.w = 0.4, 1.0
            answer = service.call_async(request)
            executor.spin_until_future_complete(answer, timeout_sec=10)
            assert answer.result().success and 'base_link' in answer.result().message
            deadline = time.monotonic() + 10
            while not any(
                t.child_frame_id == 'world' and t.transform.translation.x == 0.4
                for m in statics
                for t in m.transforms
            ):
                assert time.monotonic() < deadline, 'the new registration on /tf_static'
                executor.spin_once(timeout_sec=0.05)
            client.destroy_node()
    print(f'\nthe node said ready {started:.1f} s after its start')
