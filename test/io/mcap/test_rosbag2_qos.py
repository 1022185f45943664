"""The offered_qos_profiles channel metadata (io/mcap/rosbag2_qos.py), read back by the mcap library
and rosbags' own rosbag2 QoS parser."""

import pytest
import yaml

pytest.importorskip('rclpy')

from mcap.reader import make_reader  # noqa: E402
from rosbags.highlevel import AnyReader  # noqa: E402
from rosbags.rosbag2.metadata import QosDurability, QosReliability  # noqa: E402

from support.mcap_samples import TOPICS  # noqa: E402
from tissue_sim_ros.io import mcap as ml  # noqa: E402
from tissue_sim_ros.ros.messages import conversions as cv  # noqa: E402


def test_offered_qos_profiles_in_channel_metadata(recorded):
    path, _ = recorded
    with open(path, 'rb') as f:
        channels = {c.topic: c for c in make_reader(f).get_summary().channels.values()}
    for topic, (_, qos) in TOPICS.items():
        text = channels[topic].metadata['offered_qos_profiles']
        if qos is None:
            assert text == ''
            continue
        profiles = yaml.safe_load(text)
        assert isinstance(profiles, list) and len(profiles) == 1
        p = profiles[0]
        assert p['reliability'] == qos['reliability']
        assert p['durability'] == qos.get('durability', 'volatile')
        assert p['history'] == 'keep_last' and p['depth'] == qos['depth']
        for key in ('deadline', 'lifespan', 'liveliness_lease_duration'):
            assert p[key] == {'sec': 0, 'nsec': 0}
        assert set(p) == {'history', 'depth', 'reliability', 'durability', 'deadline',
                          'lifespan', 'liveliness', 'liveliness_lease_duration',
                          'avoid_ros_namespace_conventions'}
    # rosbags parses the same YAML with its own rosbag2 QoS parser
    with AnyReader([path]) as reader:
        conns = {c.topic: c for c in reader.connections}
        surface = conns['tissue/surface'].ext.offered_qos_profiles[0]
        wrench = conns['needle/wrench'].ext.offered_qos_profiles[0]
    assert surface.durability == QosDurability.TRANSIENT_LOCAL
    assert surface.reliability == QosReliability.RELIABLE and surface.depth == 1
    assert wrench.durability == QosDurability.VOLATILE


def test_qos_profile_validation():
    p = ml.qos_profile({'reliability': 'BEST_EFFORT', 'deadline_ns': 1_500_000_000})
    assert p['reliability'] == 'best_effort' and p['deadline'] == {'sec': 1, 'nsec': 500_000_000}
    with pytest.raises(ValueError, match='unknown keys'):
        ml.qos_profile({'durabilty': 'transient_local'})
    with pytest.raises(ValueError, match='qos.durability'):
        ml.qos_profile({'durability': 'latched'})
    assert ml.qos_profiles_yaml(None) == ''
    assert '&' not in ml.qos_profiles_yaml({})  # no YAML anchors for rosbag2's yaml-cpp


def test_qos_from_rclpy_profile_is_accepted():
    from rclpy.qos import DurabilityPolicy, QoSProfile
    d = cv.qos_to_dict(QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    p = ml.qos_profile(d)
    assert (p['durability'], p['depth'], p['history']) == ('transient_local', 1, 'keep_last')
