"""Every node parameter (ros/parameters.py): the parameter file lists them with their defaults, the
help lists them, and an impossible value is refused by name and value."""

import pytest
import yaml

rclpy = pytest.importorskip('rclpy')

from rclpy.parameter import Parameter  # noqa: E402

from support.paths import ROOT  # noqa: E402
from support.ros_clients import DOMAIN_ID  # noqa: E402
from support.ros_harness import shared_scene  # noqa: E402
from tissue_sim_ros.ros import node as node_mod  # noqa: E402


def test_parameter_file_lists_every_parameter_with_its_default():
    data = yaml.safe_load((ROOT / 'config' / 'tissue_sim.yaml').read_text())
    flat = {}

    def walk(d, prefix=''):
        for k, v in d.items():
            if isinstance(v, dict):
                walk(v, f'{prefix}{k}.')
            else:
                flat[prefix + k] = v
    walk(data['tissue_sim']['ros__parameters'])
    declared = {p.name: p.default for p in node_mod.PARAMETERS}
    assert flat == declared
    assert all(type(flat[k]) is type(declared[k]) for k in flat)  # 50.0, not 50


def test_help_lists_every_parameter():
    text = node_mod.help_text()
    for p in node_mod.PARAMETERS:
        assert f'  {p.name} = ' in text


@pytest.mark.parametrize('name, value, words', [
    ('publish_rate_hz', 0.0, ['publish_rate_hz', '0.0', 'out of range']),
    ('publish_rate_hz', 50, ['publish_rate_hz', "'50'", 'INTEGER', '50.0']),
    ('marker_rate_hz', 80.0, ['marker_rate_hz', '80.0', 'at most publish_rate_hz']),
    ('wrench.frame_id', 'tool0', ['wrench.frame_id', "'tool0'", "'needle'", "'world'"]),
    ('needle_frame_id', 'world', ['needle_frame_id', "'world'"]),
    ('on_divergence', 'explode', ['on_divergence', "'explode'", 'reset', 'hold']),
    ('input.max_jump_m', -1.0, ['input.max_jump_m', '-1.0']),
    ('recording.compression', 'gzip', ['recording.compression', "'gzip'"]),
    ('scene_file', '/nonexistent/scene.yaml', ['scene_file', '/nonexistent/scene.yaml']),
])
def test_impossible_parameters_are_refused_by_name_and_value(name, value, words):
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=DOMAIN_ID)
    try:
        with pytest.raises(node_mod.ConfigError) as err:
            node_mod.TissueSimNode(scene=shared_scene(), context=ctx,
                                   parameter_overrides=[Parameter(name, value=value)])
        for word in words:
            assert word in str(err.value), str(err.value)
    finally:
        rclpy.shutdown(context=ctx)
