"""Separate process: receive one message on each given topic and print them, serialized, as JSON.

Usage: python echo_child.py TIMEOUT_S TOPIC=pkg/Type [TOPIC=pkg/Type ...]
"""
from __future__ import annotations

import json
import sys
import time

import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message

from helpers.msgfill import msg_class

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def main() -> int:
    timeout = float(sys.argv[1])
    wanted = dict(arg.split('=', 1) for arg in sys.argv[2:])
    got: dict[str, str] = {}
    rclpy.init()
    node = rclpy.create_node('echo_child')
    for topic, kind in wanted.items():
        node.create_subscription(
            msg_class(kind), topic,
            lambda m, t=topic: got.setdefault(t, serialize_message(m).hex()), LATCHED)
    deadline = time.monotonic() + timeout
    while len(got) < len(wanted) and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
    print(json.dumps(got))
    node.destroy_node()
    rclpy.shutdown()
    return 0 if len(got) == len(wanted) else 1


if __name__ == '__main__':
    sys.exit(main())
