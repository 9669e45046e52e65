"""Samples the ROS graph during a run: which MAPs subscribe to each /map_<j>/state, at which step.

Usage: python -m helpers.graph_sampler N_MAPS. Prints 'ready' once it listens; on SIGTERM, JSON
{"samples": [[step, j, [i, ...]], ...], "nodes": most MAP nodes discovered at once, "metrics": messages heard}.
"""
from __future__ import annotations

import json
import sys

import rclpy
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from uav_flock_msgs.msg import Metrics

from helpers.lifecycle import UntilTerm

# The step the world is at now, not its history: a sampler that matched late would otherwise be handed the
# world's latched past steps (TRANSIENT_LOCAL) and read the graph of step 50 as that of step 0.
NOW_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.VOLATILE)


def main() -> int:
    n = int(sys.argv[1])
    running = UntilTerm()
    node = rclpy.create_node('graph_sampler')
    samples: list[list[object]] = []
    nodes = heard = 0  # the most MAP nodes discovery brought at once; /metrics messages received

    last = -5  # the step last sampled: every 5th step at most (with depth 1, steps may be skipped while sampling)

    def on_metrics(m: Metrics) -> None:
        nonlocal heard, last
        heard += 1
        if m.step < last + 5:
            return
        last = int(m.step)
        for j in range(n):
            subs = sorted(int(i.node_namespace.rsplit('_', 1)[1]) for i in
                          node.get_subscriptions_info_by_topic(f'/map_{j}/state')
                          if i.node_namespace.startswith('/map_'))
            samples.append([int(m.step), j, subs])

    node.create_subscription(Metrics, '/metrics', on_metrics, NOW_QOS)
    print('ready', flush=True)
    while running:
        rclpy.spin_once(node, timeout_sec=0.1)
        nodes = max(nodes, sum(1 for _, ns in node.get_node_names_and_namespaces() if ns.startswith('/map_')))
    print(json.dumps({'samples': samples, 'nodes': nodes, 'metrics': heard}), flush=True)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
