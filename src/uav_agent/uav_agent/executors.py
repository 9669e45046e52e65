"""The executor every uav-flock process spins: rclpy's EventsExecutor where this rclpy has it.

The default executor rebuilds a wait set over all of a node's entities for every callback; a world node
with one subscription and one publisher per MAP then spends most of a step doing so. The events executor
dispatches each callback directly.
"""
from __future__ import annotations

from rclpy.executors import Executor, SingleThreadedExecutor


def make_executor() -> Executor:
    try:
        from rclpy.experimental import EventsExecutor
    except ImportError:  # rclpy before Jazzy
        return SingleThreadedExecutor()
    return EventsExecutor()
