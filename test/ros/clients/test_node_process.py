"""The node as a child process (ros/clients/node_process.py): a refusal reaches the user with the
node's reason."""

import os

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
