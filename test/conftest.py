"""Shared fixtures: small meshes, a liver-like material, the TypeScript MCAP reader, the node in
process on a private ROS graph. Shared helpers that are not fixtures are in test/support/."""
import gc
import json
import shutil
import subprocess

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


@pytest.fixture(scope='session')
def mcap_js(tmp_path_factory):
    """The TypeScript @mcap/core reader with CRC checks (support/mcap_js.py), installed once per
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
    from support.mcap_js import _JS
    script = d / 'check.mjs'
    script.write_text(_JS)

    def run(*paths):
        res = subprocess.run([node, str(script), *map(str, paths)], capture_output=True,
                             text=True, timeout=120, cwd=d)
        assert res.returncode == 0, res.stderr
        return json.loads(res.stdout)
    return run


@pytest.fixture
def _private_ros(monkeypatch):
    """Localhost discovery on this process's own domain (autouse for everything under test/ros/)."""
    from support.ros_clients import DOMAIN_ID
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('ROS_DOMAIN_ID', str(DOMAIN_ID))


@pytest.fixture
def harness(_private_ros):
    """make(scene=None, slow_down=None, **params): the node and a client in this process
    (support/ros_harness.py), discovered by each other; all closed at the end of the test."""
    from support.ros_harness import Harness
    made = []

    def make(scene=None, slow_down=None, **params):
        h = Harness(scene, slow_down, **params)
        made.append(h)
        h.wait_matched()
        return h
    # as tissue_sim_node's main does: what exists now stays out of the collector's reach. In a
    # whole-suite run on a cold numba cache the test process holds the compilers' leftovers, and
    # full collections stalled the in-process node long enough to miss ticks (47.5 Hz once)
    gc.collect()
    gc.freeze()
    yield make
    for h in made:
        h.close()
    gc.unfreeze()
