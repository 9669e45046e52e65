"""A rogue publisher on /map_<id>/state: NaN, a wrong sender id and stale steps, until SIGTERM.

Usage: python -m helpers.rogue ID. Prints 'ready' once it publishes, 'published N readers R nodes M' when it ends (M: the
MAP nodes it discovered).
"""
from __future__ import annotations

import sys

import rclpy
from geometry_msgs.msg import Point, Vector3
from uav_flock_msgs.msg import AgentState

from helpers.lifecycle import UntilTerm
from uav_flock_ros.qos import STATE_QOS

def main() -> int:
    target = int(sys.argv[1])
    running = UntilTerm()
    node = rclpy.create_node('rogue')
    pub = node.create_publisher(AgentState, f'/map_{target}/state', STATE_QOS)
    print('ready', flush=True)
    here = Point(x=-150.0, y=50.0, z=20.0)
    bad = [AgentState(id=target, step=1, position=Point(x=float('nan'))),
           AgentState(id=target + 2, step=1, position=here),
           AgentState(id=target, step=0, position=here, velocity=Vector3(x=float('inf')))]
    n = readers = nodes = 0
    while running:
        pub.publish(bad[n % len(bad)])
        n += 1
        readers = max(readers, pub.get_subscription_count())
        if n % 100 == 0:  # what discovery brought: the run's nodes, whether or not their readers matched
            nodes = max(nodes, sum(1 for _, ns in node.get_node_names_and_namespaces() if ns.startswith('/map_')))
        rclpy.spin_once(node, timeout_sec=0.005)
    print(f'published {n} readers {readers} nodes {nodes}', flush=True)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
