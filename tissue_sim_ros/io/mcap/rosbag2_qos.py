"""A publisher's offered QoS in the form rosbag2 stores it (MCAP channel metadata).

rosbag2 (Jazzy, bag metadata version 9) keeps ``offered_qos_profiles`` as a YAML list of
profiles, policies as strings (``reliable``, ``transient_local``, ``keep_last``, ``automatic``)
and durations as ``{sec, nsec}``; ``ros2 bag play`` reads it back to offer the same QoS.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import yaml

from tissue_sim_ros.units import NS_PER_S

__all__ = ['qos_profile', 'qos_profiles_yaml']

_QOS_POLICIES = {
    'history': ('keep_last', 'keep_all', 'system_default'),
    'reliability': ('reliable', 'best_effort', 'system_default', 'best_available'),
    'durability': ('volatile', 'transient_local', 'system_default', 'best_available'),
    'liveliness': ('automatic', 'manual_by_topic', 'system_default', 'best_available'),
}
_QOS_DURATIONS = ('deadline', 'lifespan', 'liveliness_lease_duration')
_QOS_DEFAULTS = {
    'history': 'keep_last', 'depth': 10, 'reliability': 'reliable', 'durability': 'volatile',
    'liveliness': 'automatic', 'avoid_ros_namespace_conventions': False,
}


def _duration(key: str, value) -> dict[str, int]:
    """{sec, nsec} from int ns or from a {sec, nsec} mapping."""
    if isinstance(value, Mapping):
        sec, nsec = int(value['sec']), int(value['nsec'])
    else:
        ns = int(value)
        if ns < 0:
            raise ValueError(f'qos.{key}: {ns} ns; expected >= 0 (0 = unspecified)')
        sec, nsec = divmod(ns, NS_PER_S)
    return {'sec': sec, 'nsec': nsec}


def qos_profile(qos: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """One rosbag2 QoS profile dict (key order as rosbag2 writes it) from a partial dict.

    Keys: history, depth, reliability, durability, liveliness (names as in rmw, any case),
    deadline / lifespan / liveliness_lease_duration (int ns or {'sec', 'nsec'}; also with a
    ``_ns`` suffix), avoid_ros_namespace_conventions. Missing keys take the defaults of a
    reliable volatile keep-last-10 publisher; unknown keys or values raise ValueError.
    """
    given = dict(qos or {})
    for key in list(given):
        if key.endswith('_ns') and key[:-3] in _QOS_DURATIONS:
            given[key[:-3]] = given.pop(key)
    allowed = (set(_QOS_POLICIES) | set(_QOS_DURATIONS)
               | {'depth', 'avoid_ros_namespace_conventions'})
    unknown = sorted(set(given) - allowed)
    if unknown:
        raise ValueError(f'qos: unknown keys {unknown}; expected some of {sorted(allowed)}')
    merged = {**_QOS_DEFAULTS, **given}
    policies = {}
    for key, choices in _QOS_POLICIES.items():
        value = str(getattr(merged[key], 'name', merged[key])).lower()
        if value not in choices:
            raise ValueError(f'qos.{key}: {merged[key]!r}; expected one of {list(choices)}')
        policies[key] = value
    depth = int(merged['depth'])
    if depth < 0:
        raise ValueError(f'qos.depth: {depth}; expected >= 0')
    durations = {key: _duration(key, merged.get(key, 0)) for key in _QOS_DURATIONS}
    return {  # a fresh dict per duration: no YAML anchors/aliases in the dump
        'history': policies['history'],
        'depth': depth,
        'reliability': policies['reliability'],
        'durability': policies['durability'],
        'deadline': durations['deadline'],
        'lifespan': durations['lifespan'],
        'liveliness': policies['liveliness'],
        'liveliness_lease_duration': durations['liveliness_lease_duration'],
        'avoid_ros_namespace_conventions': bool(merged['avoid_ros_namespace_conventions']),
    }


def qos_profiles_yaml(qos: Mapping[str, Any] | None) -> str:
    """``offered_qos_profiles`` channel metadata: a YAML list with one profile, or '' for None.

    The form is rosbag2 Jazzy's: policy names as strings. rosbag2 reads a bare .mcap (no
    ``rosbag2`` metadata record) with metadata version 9, where policies must be strings; an
    empty string makes ``ros2 bag play`` use its default QoS for the topic.
    """
    if qos is None:
        return ''
    return yaml.safe_dump([qos_profile(qos)], sort_keys=False, default_flow_style=False)
