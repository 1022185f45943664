"""A client of the node on this process's private ROS domain: its subscriptions to every output,
service calls, diagnostics as values. (rclpy is imported where it is needed.)"""
import os
import time

#: this process's ROS domain for the node in process (test/conftest.py's _private_ros)
DOMAIN_ID = 60 + os.getpid() % 50


def subscribe_node_outputs(client, keeper, *, rosout=False):
    """Subscribe ``client`` to every output of tissue_sim with the QoS the node offers; keeper(key)
    gives each topic's callback ('wrench', 'nodes', 'surface', 'marker', 'diag', 'targets', 'log')."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseArray, WrenchStamped
    from rcl_interfaces.msg import Log
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2
    from shape_msgs.msg import Mesh
    from visualization_msgs.msg import Marker
    reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    topics = [('wrench', WrenchStamped, 'needle/wrench', reliable),
              ('nodes', PointCloud2, 'tissue/nodes', reliable),
              ('surface', Mesh, 'tissue/surface', latched),
              ('marker', Marker, 'tissue/marker', reliable),
              ('diag', DiagnosticArray, '/diagnostics', reliable),
              ('targets', PoseArray, 'tissue/targets', reliable)]
    if rosout:
        topics.append(('log', Log, '/rosout', QoSProfile(depth=1000)))
    for key, msg_type, topic, qos in topics:
        client.create_subscription(msg_type, topic, keeper(key), qos)
    return reliable


def call_service(client, request, timeout):
    """Call a service from a client whose node another thread spins; the response (asserts it
    comes within ``timeout`` seconds)."""
    assert client.wait_for_service(timeout_sec=timeout)
    future = client.call_async(request)
    deadline = time.monotonic() + timeout
    while not future.done():
        assert time.monotonic() < deadline, 'service call timed out'
        time.sleep(0.005)
    return future.result()


def diag_values(msg):
    """{status name: (level, message, {key: value})} of a DiagnosticArray."""
    out = {}
    for st in msg.status:
        level = st.level[0] if isinstance(st.level, (bytes, bytearray)) else int(st.level)
        out[st.name] = (level, st.message, {kv.key: kv.value for kv in st.values})
    return out


def wait_until(read, accept, timeout=10.0, what='the condition'):
    """Poll ``read()`` until ``accept(value)``; the value (asserts it comes within ``timeout``
    seconds, a bound generous enough for a loaded machine)."""
    deadline = time.monotonic() + timeout
    while True:
        value = read()
        if accept(value):
            return value
        assert time.monotonic() < deadline, f'{what}: not reached in {timeout} s (last: {value!r})'
        time.sleep(0.02)
