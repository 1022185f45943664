"""A ROS client that only listens to the node's wrench and point cloud: the extra subscriber a lab
has (a controller, RViz, a logger), run beside the node by ``tissue-sim node-bench --load N``.

``python -m tissue_sim_ros.ros.clients.listener`` (on the node's ROS domain) prints one JSON line
``{"ready": true}`` once both topics have a publisher, and on SIGINT or SIGTERM (after taking what
already arrived) one JSON line with what it received per topic: the count, the rate over the time
between its first and last message as the middleware received them (not when this process, busy
or starved, got round to taking them), and the rate at which they were sent (their publishers'
source timestamps): the receipt rate still bunches when the listener's own middleware thread is
starved (92 Hz for messages sent at 48 Hz, two busy processes on two cores), the sent rate does not.
"""
from __future__ import annotations

import json
import signal
import sys
import threading
import time

from tissue_sim_ros.units import NS_PER_S

#: what the listener subscribes to: name in its report -> (topic, message type as module.Class)
TOPICS = {'wrench': ('needle/wrench', 'geometry_msgs.msg.WrenchStamped'),
          'cloud': ('tissue/nodes', 'sensor_msgs.msg.PointCloud2')}
#: messages kept per topic until taken: 2 s of the 50 Hz wrench
QUEUE_DEPTH = 100


class Arrivals:
    """Count and first/last arrival and send times of one topic's messages (a subscription
    callback that takes the message info: its ``received_timestamp`` is when the middleware got
    the message, its ``source_timestamp`` when the publisher sent it)."""

    def __init__(self):
        self.count, self.first_ns, self.last_ns = 0, 0, 0
        self.first_sent_ns, self.last_sent_ns = 0, 0

    def __call__(self, _message, info) -> None:
        now = info.get('received_timestamp') or time.time_ns()
        sent = info.get('source_timestamp') or 0
        if not self.count:
            self.first_ns, self.first_sent_ns = now, sent
        self.count, self.last_ns, self.last_sent_ns = self.count + 1, now, sent

    def summary(self) -> dict:
        return {'count': self.count, 'rate_hz': _rate(self.count, self.first_ns, self.last_ns),
                'sent_rate_hz': _rate(self.count, self.first_sent_ns, self.last_sent_ns)}


def _rate(count: int, first_ns: int, last_ns: int) -> float:
    """(count - 1) messages over the span between the first and the last; 0 without a span."""
    span_s = (last_ns - first_ns) / NS_PER_S
    return (count - 1) / span_s if count > 1 and span_s > 0 else 0.0


def _message_type(dotted: str):
    from importlib import import_module
    module, name = dotted.rsplit('.', 1)
    return getattr(import_module(module), name)


def _drain(rclpy, node, arrivals: dict, quiet_s: float = 0.2, most: int = 50) -> None:
    """Take what already arrived before reporting: spin until ``quiet_s`` passes with nothing new
    (a starved listener may hold messages it has not yet taken when the stop signal comes)."""
    for _ in range(most):
        before = sum(a.count for a in arrivals.values())
        rclpy.spin_once(node, timeout_sec=quiet_s)
        if sum(a.count for a in arrivals.values()) == before:
            return


def main() -> int:
    """Listen until SIGINT or SIGTERM; print the arrivals as JSON."""
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rclpy.signals import SignalHandlerOptions
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('tissue_sim_listener')
    arrivals = {name: Arrivals() for name in TOPICS}
    # a deep queue: a listener starved by the busy processes beside it must not count its own
    # overwritten queue as messages the node never sent
    reliable = QoSProfile(depth=QUEUE_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
    subscriptions = [node.create_subscription(_message_type(kind), topic, arrivals[name], reliable)
                     for name, (topic, kind) in TOPICS.items()]
    ready = False
    try:
        while not stop.is_set():
            rclpy.spin_once(node, timeout_sec=0.1)
            if not ready and all(s.get_publisher_count() for s in subscriptions):
                ready = True
                print(json.dumps({'ready': True}), flush=True)
        _drain(rclpy, node, arrivals)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    print(json.dumps({name: a.summary() for name, a in arrivals.items()}), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
