"""A run's participants on Fast DDS's TCP transport with TLS (uav_flock_tools/secure.py), keyed by `uav-flock keys`:
a discovery server and real rclpy processes over real sockets. A member of the run hears it; a stranger that dials
in without a certificate, or with one of another CA, and checks nothing itself, is refused by the run's side of
the handshake and hears nothing."""
from __future__ import annotations

import re
import socket
import subprocess
import sys
from pathlib import Path

from helpers.rogue import lax_profile
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
print(f'heard {len(got)}', flush=True)
'''


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return int(s.getsockname()[1])


def test_a_member_of_the_run_hears_it_and_strangers_fail_the_handshake(tmp_path: Path, ros_env: dict[str, str]) -> None:
    keys.make(tmp_path / 'run', ['world', 'field1'])
    keys.make(tmp_path / 'other', ['field1'])
    server = ('127.0.0.1', _free_port())
    run = secure.write_profiles(keys.check(tmp_path / 'run' / 'world'), server, tmp_path / 'world')
    member = secure.write_profiles(keys.check(tmp_path / 'run' / 'field1'), server, tmp_path / 'member', ('client',))
    foreign = secure.write_profiles(keys.check(tmp_path / 'other' / 'field1'), server, tmp_path / 'foreign', ('client',))
    (tmp_path / 'foreign' / 'client.xml').write_text(lax_profile(foreign['client'].read_text(), certificate=True))
    for name, profile, certificate in (('nocert', foreign, False), ('lax', member, True)):
        (tmp_path / name).mkdir()
        (tmp_path / name / 'client.xml').write_text(lax_profile(profile['client'].read_text(), certificate))
    plain = {k: v for k, v in ros_env.items() if k != 'OPENSSL_CONF'}  # a stranger keeps its own OpenSSL defaults
    discovery = subprocess.Popen(['fast-discovery-server', '-x', str(run['server'])],
                                 env=secure.environment(ros_env, run['server']), stdout=subprocess.DEVNULL,
                                 stderr=subprocess.DEVNULL)
    talker = subprocess.Popen([sys.executable, '-c', TALKER, '60'], env=secure.environment(ros_env, run['client']),
                              stdout=subprocess.DEVNULL, stderr=open(tmp_path / 'talker.log', 'w'))
    try:
        listening = {}
        # The two strangers listen out their 10 s side by side: each hears nothing whatever the other does.
        for who, folder in (('member', None), ('member, checking nothing', 'lax'), ('other CA', 'foreign'),
                            ('no certificate', 'nocert')):
            env = secure.environment(ros_env, member['client']) if folder is None else {
                **plain, 'FASTRTPS_DEFAULT_PROFILES_FILE': str(tmp_path / folder / 'client.xml'),
                'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'}
            listening[who] = subprocess.Popen([sys.executable, '-c', LISTENER, '20' if who.startswith('member') else '10'],
                                              env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            if who.startswith('member'):  # one at a time: a member ends as soon as it has heard five
                listening[who] = subprocess.CompletedProcess(who, 0, *listening[who].communicate(timeout=60))
        heard = {who: p if isinstance(p, subprocess.CompletedProcess) else
                 subprocess.CompletedProcess(who, 0, *p.communicate(timeout=60)) for who, p in listening.items()}
    finally:
        for p in (talker, discovery):
            p.terminate()
            p.wait(10)
    said = {who: p.stdout + p.stderr for who, p in heard.items()}
    # Fast DDS logs to stdout too, also after the count (a refused handshake's error, from its own thread)
    counts = {who: ' '.join(re.findall(r'^heard (\d+)$', p.stdout, re.M)) for who, p in heard.items()}
    assert counts['member'] == '5', said['member'] + (tmp_path / 'talker.log').read_text()
    # The strangers' profile itself works: with the run's certificate it hears the run. Only the certificate differs.
    assert counts['member, checking nothing'] == '5', said['member, checking nothing']
    assert counts['other CA'] == '0', said['other CA']
    assert counts['no certificate'] == '0', said['no certificate']


def test_a_connection_that_never_starts_its_handshake_does_not_stall_a_secured_run(
        tmp_path: Path, ros_env: dict[str, str]) -> None:
    """Fast DDS accepts the next connection only once the last one's handshake has ended. A connection to the
    discovery server made before any member's, and silent for the whole run, held every MAP out (0 of 8 seen) until
    it closed; `up` restarts the stalled server and the run ends as `sim` flies it, byte for byte."""
    from helpers.runs import cli, ended, up
    from uav_flock_tools.domains import DISCOVERY_BASE_PORT
    assert cli('keys', '--out', str(tmp_path / 'keys'), '--hosts', 'world').returncode == 0
    domain = next(d for d in range(60, 102) if _bindable(DISCOVERY_BASE_PORT + d))
    silent = subprocess.Popen([sys.executable, '-m', 'helpers.silent', '127.0.0.1', str(DISCOVERY_BASE_PORT + domain)],
                              cwd=Path(__file__).resolve().parents[1], env=ros_env, stdout=subprocess.PIPE, text=True)
    run = tmp_path / 'up'
    args = ('--scenario', 'paper', '--maps', '8', '--duration', '5')
    proc = up(*args, '--listen', '127.0.0.1', '--domain-id', str(domain), '--agents-here', '8',
              '--secure', str(tmp_path / 'keys' / 'world'), '--out', str(run), env=ros_env)
    try:
        said = ended(proc, 180, run)
    finally:
        silent.terminate()
        heard = silent.communicate(timeout=10)[0]
    assert 'ready' in heard.split('\n'), 'the silent connection was never made: nothing listened on the server\'s port'
    assert proc.returncode == 0, said
    assert re.search(r'^uav-flock up: the discovery server stopped accepting connections for 5 s: restarted \(1\)',
                     said, re.M), said
    assert cli('sim', *args, '--out', str(tmp_path / 'sim')).returncode == 0
    for name in ('trajectory.csv', 'metrics.csv'):
        assert (run / name).read_bytes() == (tmp_path / 'sim' / name).read_bytes(), name


def _bindable(port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind(('127.0.0.1', port))
        except OSError:
            return False
        return True
