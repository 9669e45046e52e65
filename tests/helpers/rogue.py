"""A rogue publisher on /map_<id>/state until SIGTERM: malformed states (NaN, a wrong sender id, stale steps), or with
STEPS, well-formed states with a false position for every step below STEPS, what a stranger on the LAN would publish
to pull a formation apart.

Usage: python -m helpers.rogue ID [STEPS]. Prints 'ready' once it publishes, 'published N readers R nodes M' when it
ends (R: the readers its writer matched; M: the MAP nodes it discovered).
"""
from __future__ import annotations

import re
import sys

import rclpy
from geometry_msgs.msg import Point, Vector3
from uav_flock_msgs.msg import AgentState

from helpers.lifecycle import UntilTerm
from uav_flock_ros.qos import STATE_QOS


def lax_profile(member: str, certificate: bool) -> str:
    """What a stranger would make of a run member's Fast DDS profile (secure.profile, of keys of its own): TLS that
    checks nothing itself, and no certificate at all unless `certificate`."""
    member = re.sub(r'<verify_mode>.*?</verify_mode>', '<verify_mode><verify>VERIFY_NONE</verify></verify_mode>', member)
    member = re.sub(r'<verify_file>.*?</verify_file>', '', member)
    if not certificate:
        member = re.sub(r'<(private_key_file|cert_chain_file)>.*?</\1>', '', member)
    return member


def states(target: int, steps: int) -> list[AgentState]:
    """What the rogue cycles through: with steps, one well-formed state a step, far from every cluster and flying
    away (a neighbour that believed it would follow it out); without, malformed ones."""
    if steps:
        return [AgentState(id=target, step=k, position=Point(x=400.0, y=-300.0, z=20.0), velocity=Vector3(x=20.0),
                           mode=AgentState.MODE_STATIC, goal=0) for k in range(steps)]
    here = Point(x=-150.0, y=50.0, z=20.0)
    return [AgentState(id=target, step=1, position=Point(x=float('nan'))),
            AgentState(id=target + 2, step=1, position=here),
            AgentState(id=target, step=0, position=here, velocity=Vector3(x=float('inf')))]


def main() -> int:
    target = int(sys.argv[1])
    running = UntilTerm()
    node = rclpy.create_node('rogue')
    pub = node.create_publisher(AgentState, f'/map_{target}/state', STATE_QOS)
    print('ready', flush=True)
    sent = states(target, int(sys.argv[2]) if len(sys.argv) > 2 else 0)
    n = readers = nodes = 0
    while running:
        pub.publish(sent[n % len(sent)])
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
