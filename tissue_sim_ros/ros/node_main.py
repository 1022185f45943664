"""The node process: rclpy set-up, signals, the executor loop and a clean close.

SIGINT and SIGTERM set a flag the loop checks, so the recording is closed with its summary
before rclpy shuts down; the start-up's objects are frozen out of the garbage collector.
"""
from __future__ import annotations

import gc
import signal
import sys
import threading

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

from tissue_sim_ros.errors import ConfigError

__all__ = ['make_executor', 'run']


def make_executor(kind: str, context=None):
    """'events': rclpy's EventsExecutor (callbacks dispatched from C++; the node's tick costs a
    fraction of the SingleThreadedExecutor's, which rebuilds its wait set in Python at every
    wake), or 'single_threaded'."""
    if kind == 'events':
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    return SingleThreadedExecutor(context=context)


def run(node_class, help_text, argv=None) -> int:
    """Run the node until SIGINT or SIGTERM; 0 on a clean stop, 2 on a refused parameter."""
    args = list(sys.argv if argv is None else argv)
    user_args = args[1:args.index('--ros-args')] if '--ros-args' in args else args[1:]
    if '-h' in user_args or '--help' in user_args:
        print(help_text())
        return 0
    stop = threading.Event()
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    previous = {sig: signal.signal(sig, lambda signum, frame: stop.set())
                for sig in (signal.SIGINT, signal.SIGTERM)}
    node = None
    try:
        try:
            node = node_class()
        except ConfigError as exc:
            print(f'tissue_sim_node: {exc}', file=sys.stderr)
            return 2
        executor = make_executor(node.config.executor)
        executor.add_node(node)
        # the engine thread and the executor share the GIL: a thread waiting for it gets it within
        # 1 ms (Python's default lets a running thread keep it for 5 ms, a late tick)
        sys.setswitchinterval(0.001)
        # the start-up's objects (numba, rclpy, the scene) move out of the collector's reach: a
        # full collection would walk them all, a 40-60 ms stall of the tick every few seconds
        gc.collect()
        gc.freeze()
        try:
            while not stop.is_set() and rclpy.ok():
                executor.spin_once(timeout_sec=0.1)
        except ExternalShutdownException:   # rclpy shut down from outside: close cleanly below
            return 0
        return 0
    finally:
        if node is not None:
            node.close()  # the recording first: it must not depend on rclpy shutting down well
            node.destroy_node()
        rclpy.try_shutdown()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
