"""Shared fixtures: small meshes, a liver-like material, the TypeScript MCAP reader, the node's
output subscriptions."""
import json
import shutil
import subprocess
import time

import numpy as np
import pytest

import tissue_sim_ros as ts


def pytest_configure(config):
    config.addinivalue_line('markers', 'slow: takes tens of seconds (deselect with -m "not slow")')


@pytest.fixture(scope='session')
def liver():
    return ts.Material(young_modulus=5e3, poisson_ratio=0.45, density=1060.0)


@pytest.fixture(scope='session')
def jittered_block():
    """An irregular mesh: a 4x3x3 box whose interior nodes are moved randomly (still valid)."""
    mesh = ts.box_mesh(size=(0.04, 0.03, 0.03), divisions=(4, 3, 3))
    positions = mesh.rest_positions.copy()
    interior = np.setdiff1d(np.arange(mesh.n_nodes), mesh.surface_nodes())
    rng = np.random.default_rng(7)
    positions[interior] += rng.uniform(-0.002, 0.002, size=(len(interior), 3))
    return ts.make_mesh(positions, mesh.tetrahedra)


def static_solve(model, constrained_dofs, prescribed_values):
    """Solve K u = 0 on the free DOFs with u fixed on ``constrained_dofs`` (scipy, independent of the explicit solver)."""
    import scipy.sparse.linalg
    stiffness = model.stiffness_matrix().tocsr()
    n_dofs = stiffness.shape[0]
    u = np.zeros(n_dofs)
    u[constrained_dofs] = prescribed_values
    free = np.setdiff1d(np.arange(n_dofs), constrained_dofs)
    rhs = -stiffness[free][:, constrained_dofs] @ u[constrained_dofs]
    u[free] = scipy.sparse.linalg.spsolve(stiffness[free][:, free].tocsc(), rhs)
    return u.reshape(-1, 3)


@pytest.fixture(scope='session')
def mcap_js(tmp_path_factory):
    """The TypeScript @mcap/core reader with CRC checks (test_mcap_log._JS), installed once per
    run with npm: run(*paths) -> its JSON verdict per file. Skipped without node/npm/registry."""
    node, npm = shutil.which('node'), shutil.which('npm')
    if not (node and npm):
        pytest.skip('node and npm are not both on PATH')
    d = tmp_path_factory.mktemp('mcapjs')
    try:
        r = subprocess.run([npm, 'install', '--no-audit', '--no-fund', '--loglevel=error',
                            '@mcap/core', 'fzstd'], cwd=d, capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        pytest.skip('npm install @mcap/core timed out (no registry?)')
    if r.returncode != 0 or not (d / 'node_modules' / '@mcap' / 'core').is_dir():
        pytest.skip(f'npm install @mcap/core failed (no registry?): {r.stderr[-300:]}')
    from test_mcap_log import _JS
    script = d / 'check.mjs'
    script.write_text(_JS)

    def run(*paths):
        res = subprocess.run([node, str(script), *map(str, paths)], capture_output=True,
                             text=True, timeout=120, cwd=d)
        assert res.returncode == 0, res.stderr
        return json.loads(res.stdout)
    return run


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
