"""The node's MCAP log: which topics it holds, with what schema and QoS, and its metadata.

Every message in (the wire bytes as received) and out (serialized once: the same bytes are
published and recorded) goes to one MCAP file per run, named by the start time
(:class:`tissue_sim_ros.io.mcap.McapRecorder`, which writes on its own thread: a write here
is a queue append, never a wait on the disk). The metadata record holds the scene, the
parameters and where they came from. The engine's trace (:mod:`~tissue_sim_ros.ros.loop.trace`,
``~/engine_trace``, recorded only, not published; its bytes are written by
:class:`~tissue_sim_ros.ros.messages.cdr_bytes.TraceBytes`) makes the run replayable. ``tissue/nodes``, most of a log's bytes, is recorded at
``recording.nodes_rate_hz`` (every k-th tick) while it is still published every tick (to its
subscribers: with none, only the recorded ticks build it).
"""
from __future__ import annotations

import datetime as _dt

from tissue_sim_ros.ros.loop.trace import TRACE_TYPE
from tissue_sim_ros.ros.parameters import parameters_yaml
from tissue_sim_ros.ros.messages.topics import (DIAGNOSTICS_QOS, MARKER_QOS, NODE_TOPIC_TYPES, NODES_QOS, PLAN_QOS,
                                                READY_QOS, SERVICE_EVENT_QOS, SURFACE_QOS, TF_QOS,
                                                TF_STATIC_QOS,
                                                WRENCH_QOS)

__all__ = ['node_log_topics', 'open_node_log', 'every_kth_tick', 'record_service_call']

def every_kth_tick(publish_rate_hz: float, rate_hz: float) -> int:
    """k such that every k-th tick gives ``rate_hz`` (0: never, for a rate of 0)."""
    return max(1, round(publish_rate_hz / rate_hz)) if rate_hz > 0 else 0


def node_log_topics(node, qos_to_dict) -> list:
    """(resolved topic, ROS type, QoS dict) of every channel of the node's log: its publishers
    (tissue/targets only for a scene with targets: nothing is published on it otherwise; a shape
    and a wrench per needle), its pose subscriptions (one per needle), /tf and /tf_static (what it
    broadcasts and what it receives from others), ``~/ready`` and its services' event topics."""
    needles = {}
    for (pose, wrench), pose_sub, wrench_pub in zip(node.needle_topics, node.pose_subs, node.wrench_pubs):
        needles[wrench] = (wrench_pub, WRENCH_QOS, NODE_TOPIC_TYPES['needle/wrench'])
        needles[pose] = (pose_sub, node.pose_qos, NODE_TOPIC_TYPES['needle/pose'])
    for shape, shape_pub in zip(node.shapes.topics, node.shapes.publishers):
        needles[shape] = (shape_pub, WRENCH_QOS, NODE_TOPIC_TYPES['needle/shape'])
    entities = {'tissue/nodes': (node.nodes_pub, NODES_QOS),
                'tissue/surface': (node.surface_pub, SURFACE_QOS),
                'tissue/marker': (node.marker_pub, MARKER_QOS),
                'tissue/targets': (node.targets_pub if len(node.scene.targets) else None, NODES_QOS),
                '/diagnostics': (node.diagnostics_pub, DIAGNOSTICS_QOS),
                'plan/candidate': (node.candidate_sub, PLAN_QOS),
                'plan/prediction': (node.prediction_pub, PLAN_QOS),
                '/tf': (node.tf_subs[0], TF_QOS), '/tf_static': (node.tf_subs[1], TF_STATIC_QOS),
                '~/ready': (node.ready_pub, READY_QOS)}
    entities = {name: (entity, profile, NODE_TOPIC_TYPES[name]) for name, (entity, profile) in entities.items()}
    topics = [(entity.topic_name, type_name, qos_to_dict(profile))
              for entity, profile, type_name in [*needles.values(), *entities.values()] if entity is not None]
    topics.append((node.trace_topic, TRACE_TYPE, qos_to_dict(WRENCH_QOS)))
    from tissue_sim_ros.ros.services import SERVICE_TYPES
    return topics + [(node._event_topic(node.node_services.services[name]), f'{type_name}_Event',
                      qos_to_dict(SERVICE_EVENT_QOS)) for name, type_name in SERVICE_TYPES.items()]


def open_node_log(config, *, scene_text: str, node_name: str, node_fqn: str, topics,
                  scene_spec: dict | None = None, engine_threads: int | None = None):
    """A McapRecorder for this run in ``config.recording_directory`` with the run's metadata;
    ``topics``: (resolved topic, ROS type, QoS as a dict) of every channel it will hold.
    ``scene_spec``: every scene key as the engine used it (the file's text may not say all: a
    scene given to the node in code, defaults), ``engine_threads``: the engine's numba threads:
    what ``tissue-sim replay`` needs besides the trace."""
    import yaml

    from tissue_sim_ros.io.mcap import McapRecorder
    metadata = {
        'scene': str(scene_text),
        'scene_spec': yaml.safe_dump(scene_spec, sort_keys=False) if scene_spec is not None else '',
        'engine_threads': '' if engine_threads is None else str(int(engine_threads)),
        'scene_file': config.scene_file or '(packaged default)',
        'parameters': parameters_yaml(config.values, node_name),
        'node': node_fqn,
        'started_at': _dt.datetime.now(_dt.timezone.utc).isoformat(),
        'ros_distro': 'jazzy',
    }
    recorder = McapRecorder.create(
        config.recording_directory, prefix=config.recording_prefix, metadata=metadata,
        chunk_interval_s=config.recording_chunk_interval_s,
        compression=config.recording_compression)
    for topic, type_name, qos in topics:
        recorder.add_topic(topic, type_name, qos)
    return recorder


def record_service_call(recorder, topic, srv_type, request, response, now_ns, sequence, serialize):
    """Record a service call as rosbag2 records service introspection (contents): a
    REQUEST_RECEIVED event with the request, then a RESPONSE_SENT event with the response, on
    ``<service>/_service_event``; ``serialize``: rclpy's serialize_message (passed in, so that
    this module imports no rclpy)."""
    from service_msgs.msg import ServiceEventInfo

    from tissue_sim_ros.ros.messages.conversions import ns_to_stamp
    for event_type, requests, responses in ((ServiceEventInfo.REQUEST_RECEIVED, [request], []),
                                            (ServiceEventInfo.RESPONSE_SENT, [], [response])):
        event = srv_type.Event()
        event.info.event_type = event_type
        event.info.stamp = ns_to_stamp(now_ns)
        event.info.sequence_number = sequence
        event.request, event.response = requests, responses
        recorder.write(topic, serialize(event), now_ns)
