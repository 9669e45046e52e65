"""Participants on Fast DDS's TCP transport with TLS (uav_flock_tools/secure.py), keyed by `uav-flock keys`:
real rclpy processes over real sockets. A run's member hears the run; a stranger with another CA's
certificate fails the handshake and hears nothing."""
from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

from uav_flock_tools import keys, secure

TALKER = '''
import sys, time, rclpy
from std_msgs.msg import String
rclpy.init(); node = rclpy.create_node('talker'); pub = node.create_publisher(String, '/secret_topic', 10)
end = time.time() + float(sys.argv[1])
while time.time() < end:
    pub.publish(String(data='hello')); rclpy.spin_once(node, timeout_sec=0.2)
'''
LISTENER = '''
import sys, time, rclpy
from std_msgs.msg import String
rclpy.init(); node = rclpy.create_node('listener'); got = []
node.create_subscription(String, '/secret_topic', lambda m: got.append(m.data), 10)
end = time.time() + float(sys.argv[1])
while time.time() < end and len(got) < 5:
    rclpy.spin_once(node, timeout_sec=0.2)
print(len(got))
'''


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return int(s.getsockname()[1])


def test_a_member_of_the_run_hears_it_and_a_stranger_fails_the_handshake(
        tmp_path: Path, ros_env: dict[str, str]) -> None:
    keys.make(tmp_path / 'run', ['world', 'field1'])
    keys.make(tmp_path / 'other', ['field1'])
    port = _free_port()
    files = {}
    for name, folder, listen, peers in (('world', tmp_path / 'run' / 'world', port, ()),
                                        ('member', tmp_path / 'run' / 'field1', None, (('127.0.0.1', port),)),
                                        ('stranger', tmp_path / 'other' / 'field1', None, (('127.0.0.1', port),))):
        files[name] = tmp_path / f'{name}.xml'
        files[name].write_text(secure.profile(keys.check(folder), listen, peers))
    talker = subprocess.Popen([sys.executable, '-c', TALKER, '40'], env=secure.environment(ros_env, files['world']),
                              stdout=subprocess.DEVNULL, stderr=open(tmp_path / 'talker.log', 'w'))
    try:
        member = subprocess.run([sys.executable, '-c', LISTENER, '20'], env=secure.environment(ros_env, files['member']),
                                capture_output=True, text=True, timeout=60)
        stranger = subprocess.run([sys.executable, '-c', LISTENER, '10'],
                                  env=secure.environment(ros_env, files['stranger']), capture_output=True, text=True,
                                  timeout=60)
    finally:
        talker.terminate()
        talker.wait(10)
    heard = [p.stdout.strip().splitlines()[-1] if p.stdout.strip() else '' for p in (member, stranger)]
    assert heard[0] == '5', member.stdout + member.stderr + (tmp_path / 'talker.log').read_text()
    assert heard[1] == '0', stranger.stdout + stranger.stderr  # Fast DDS logs to stdout, the count comes last
    assert 'Handshake failed' in stranger.stdout + stranger.stderr, 'refused at the TLS handshake, not unheard'
