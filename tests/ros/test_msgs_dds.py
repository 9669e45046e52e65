"""Every uav_flock_msgs type crosses DDS between two processes unchanged, field for field."""
from __future__ import annotations

import json
import random
import subprocess
import sys
from pathlib import Path

import rclpy
import uav_flock_msgs.msg as flock_msgs
from rclpy.serialization import deserialize_message

from helpers.echo_child import LATCHED
from helpers.msgfill import diff, fill

MSG_TYPES = sorted(
    name for name in dir(flock_msgs)
    if isinstance(getattr(flock_msgs, name), type) and hasattr(getattr(flock_msgs, name), 'get_fields_and_field_types'))
TESTS_DIR = Path(__file__).resolve().parents[1]


def test_package_defines_the_data_flow_messages() -> None:
    assert set(MSG_TYPES) >= {'AgentState', 'Sensing', 'NeighborList', 'Command', 'Association',
                              'Metrics', 'Users', 'Clusters', 'FailureEvent'}


def test_mode_constants_match_the_paper_modes() -> None:
    s = flock_msgs.AgentState()
    assert (s.MODE_DYNAMIC, s.MODE_CONNECT, s.MODE_STATIC) == (0, 1, 2)
    assert s.goal == s.NO_GOAL == -1


def test_every_message_type_round_trips_between_processes(ros_env: dict[str, str]) -> None:
    rng = random.Random(7)
    sent = {f'/roundtrip/{name.lower()}': fill(getattr(flock_msgs, name)(), rng) for name in MSG_TYPES}
    rclpy.init()
    try:
        node = rclpy.create_node('roundtrip_pub')
        pubs = [node.create_publisher(type(m), topic, LATCHED) for topic, m in sent.items()]
        for pub, msg in zip(pubs, sent.values()):
            pub.publish(msg)
        child = subprocess.Popen(
            [sys.executable, '-m', 'helpers.echo_child', '30']
            + [f'{t}=uav_flock_msgs/{type(m).__name__}' for t, m in sent.items()],
            cwd=TESTS_DIR, env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        while child.poll() is None:  # keep serving discovery and late joiners until the child is done
            rclpy.spin_once(node, timeout_sec=0.05)
        out, err = child.communicate()
        node.destroy_node()
    finally:
        rclpy.shutdown()
    assert child.returncode == 0, f'receiver got only part of the messages: {out}\n{err}'
    received = json.loads(out)
    assert set(received) == set(sent)
    for topic, msg in sent.items():
        back = deserialize_message(bytes.fromhex(received[topic]), type(msg))
        assert diff(msg, back) == [], f'{topic} changed on the wire'
        assert back == msg
