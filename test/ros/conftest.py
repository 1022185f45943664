"""The ROS tests: every one on the private ROS graph, the node's scene file for the process tests,
and a node with two needles. (rclpy is imported by the fixtures that need it: the tests here
that need no ROS run without it.)"""
import threading
import time

import pytest

from support.paths import ROOT


@pytest.fixture(autouse=True)
def _private_ros(_private_ros):
    """Every test here on the private ROS graph (test/conftest.py's fixture of the same name)."""


@pytest.fixture(scope='module')
def scene_file(tmp_path_factory):
    """The scene the node runs: the default one on a coarse mesh, or TISSUE_SIM_TEST_SCENE."""
    from support.node_process import SCENE_OVERRIDE
    if SCENE_OVERRIDE:
        return SCENE_OVERRIDE
    import yaml
    spec = yaml.safe_load((ROOT / 'config' / 'liver_sample.yaml').read_text())
    spec['mesh'] = {'generator': 'box', 'size_m': spec['mesh']['size_m'],
                    'origin_m': spec['mesh']['origin_m'], 'divisions': [6, 6, 4]}
    path = tmp_path_factory.mktemp('scene') / 'liver_coarse.yaml'
    path.write_text('# config/liver_sample.yaml on a coarse mesh (test/ros/conftest.py)\n'
                    + yaml.safe_dump(spec, sort_keys=False))
    return str(path)


@pytest.fixture
def two_needle_node(monkeypatch):
    """A node whose scene has two needles (support/two_needles.py) and a client listening to both
    wrenches: (node, client, pose publishers by name, wrenches received by name)."""
    rclpy = pytest.importorskip('rclpy')
    from geometry_msgs.msg import PoseStamped, WrenchStamped
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from support.two_needles import DOMAIN_ID, MESH, NEEDLES
    from tissue_sim_ros.engine.scene.scene import Scene
    from tissue_sim_ros.ros.node import TissueSimNode
    from tissue_sim_ros.ros.node_main import make_executor
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=DOMAIN_ID)
    node = TissueSimNode(scene=Scene.from_file(None, mesh=MESH, needles=NEEDLES), context=ctx,
                         parameter_overrides=[Parameter('prediction.workers', value=-1)])
    client = rclpy.create_node('needles_client', context=ctx)
    reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    received = {name: [] for name in ('biopsy', 'fixation')}
    for name in received:
        client.create_subscription(WrenchStamped, f'needle/{name}/wrench', received[name].append, reliable)
    publishers = {name: client.create_publisher(PoseStamped, f'needle/{name}/pose', reliable) for name in received}
    stop = threading.Event()
    threads = []
    for n, executor in ((node, make_executor(node.config.executor, context=ctx)),
                        (client, SingleThreadedExecutor(context=ctx))):
        executor.add_node(n)
        thread = threading.Thread(target=lambda e=executor: [e.spin_once(timeout_sec=0.05)
                                                             for _ in iter(stop.is_set, True)], daemon=True)
        thread.start()
        threads.append(thread)
    deadline = time.monotonic() + 10
    while not all(p.get_subscription_count() for p in publishers.values()) or \
            not all(p.get_subscription_count() for p in node.wrench_pubs):
        assert time.monotonic() < deadline, 'node and client did not match'
        time.sleep(0.01)
    yield node, client, publishers, received
    stop.set()
    for thread in threads:
        thread.join(timeout=5)
    node.destroy_node()
    client.destroy_node()
    rclpy.shutdown(context=ctx)


@pytest.fixture
def graph():
    """make(**params): the node with those parameters and a client in this process, on the private
    graph (support/ros_graph.py), the node ticking; all closed at the end of the test."""
    pytest.importorskip('rclpy')
    pytest.importorskip('tf2_msgs.msg')
    from support.ros_graph import Graph
    made = []

    def make(**params):
        made.append(Graph(**params))
        return made[-1]
    yield make
    for g in made:
        g.close()
