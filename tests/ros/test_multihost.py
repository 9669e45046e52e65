"""One run over three hosts: real network namespaces joined by veth pairs on a bridge, DDS over UDP only, or over
TCP with TLS (`--secure`) with two strangers on the LAN.

The world (`up --listen`) runs in one namespace, two agent hosts (`agents --join`) in two others; each has
its own network stack, so nothing passes by loopback or shared memory between them (the run's transport is
UDPv4 only). The namespaces and links are removed at the end, also when the test fails.
"""
from __future__ import annotations

import re
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator, Optional

import pytest
import yaml
from helpers.runs import cli
from helpers import netns

SUBNET = '10.231.7'
HOSTS = ['world', 'a', 'b']  # at SUBNET.1, .2, .3
STRANGERS = ['nocert', 'otherca']  # at SUBNET.4, .5 in the secure run: TLS that checks nothing, no or a foreign certificate
SILENT = 'silent'  # at SUBNET.6 in the secure run: dials the discovery server and says nothing (strangers.py)
TESTS = Path(__file__).resolve().parents[1]
# What DDS discovery says in clear over UDP: the run's topic names ('rt/' + name) and its message types.
IN_CLEAR = (b'rt/map_', b'uav_flock_msgs::msg::dds_::AgentState_')


@contextmanager
def network(roles: list[str]) -> Iterator[dict[str, str]]:
    """Hosts at SUBNET.1, .2, ... in the order of roles; {role: namespace}."""
    try:
        with netns.hosts(roles, SUBNET) as names:
            yield names
    except netns.NetnsError as exc:
        pytest.fail(f'this test runs hosts as network namespaces, which cannot be made here: {exc}; '
                    'run the suite as root')


@pytest.fixture
def hosts() -> Iterator[dict[str, str]]:
    """Three hosts (world, a, b) at SUBNET.1-3."""
    with network(HOSTS) as names:
        yield names


def in_ns(ns: str, *args: str, env: dict[str, str], out: Path) -> subprocess.Popen[str]:
    """The CLI in a namespace, its output to a file (read while it runs)."""
    return subprocess.Popen(netns.cli(ns, *args),
                            stdout=open(out, 'w'), stderr=subprocess.STDOUT, text=True, env=env)


def wait_for(path: Path, pattern: str, proc: subprocess.Popen[str], timeout: float) -> re.Match[str]:
    """The first line of a growing output file that matches pattern; fails if the process ends first."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        m = re.search(pattern, path.read_text() if path.exists() else '', re.M)
        if m:
            return m
        assert proc.poll() is None, f'ended before {pattern!r}:\n{path.read_text()}'
        time.sleep(0.2)
    raise AssertionError(f'no {pattern!r} within {timeout:g} s:\n{path.read_text()}')


def ended(proc: subprocess.Popen[str], timeout: float, folder: Path) -> int:
    """proc's exit code; past the timeout, a failure showing the last lines of the terminal outputs and logs
    in folder (which MAPs a stalled step waits for, and on what)."""
    try:
        return proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        logs = sorted(folder.glob('*.out')) + sorted(folder.glob('*/logs/*.log'))
        tails = '\n'.join(f'--- {p.relative_to(folder)}\n' + '\n'.join(p.read_text(errors='replace').splitlines()[-8:])
                          for p in logs)
        pytest.fail(f'{proc.args[:8]}... still running after {timeout:.0f} s\n{tails}')


def small_scenario(paper_scenario_path: str, out: Path) -> Path:
    """Two small clusters that 8 MAPs cover whole: what the formation must recover after losing 4 of 12."""
    doc: dict[str, Any] = yaml.safe_load(Path(paper_scenario_path).read_text())
    doc.pop('policies')  # the demand allocation
    doc['users'] = {'clusters': [{'center': [-60.0, 40.0], 'spread': 8.0, 'size': 120},
                                 {'center': [-20.0, 40.0], 'spread': 8.0, 'size': 120}]}
    path = out / 'small.yaml'
    path.write_text(yaml.safe_dump(doc))
    return path


def helper_in_ns(ns: str, module: str, *args: str, env: dict[str, str]) -> subprocess.Popen[str]:
    """A helper process (tests/helpers) in a namespace, once it has printed 'ready'."""
    proc = subprocess.Popen(['ip', 'netns', 'exec', ns, sys.executable, '-m', f'helpers.{module}', *args], cwd=TESTS,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert proc.stdout is not None
    line = proc.stdout.readline()
    while line and line.strip() != 'ready':
        line = proc.stdout.readline()
    assert line, f'{module} in {ns} ended before it was ready (exit {proc.wait()})'
    return proc


@contextmanager
def captured(path: Path, env: dict[str, str]) -> Iterator[Path]:
    """Every frame between the hosts (in the bridge's namespace, where their links end) into path."""
    proc = helper_in_ns(netns.bridge(), 'capture', str(path), env=env)
    try:
        yield path
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def start(hosts: dict[str, str], tmp_path: Path, env: dict[str, str], scenario: Path, duration: str,
          here: int, a: str, b: str, refuse: bool = False, keys: Optional[Path] = None,
          before_join: Callable[[str], None] = lambda address: None
          ) -> tuple[subprocess.Popen[str], list[subprocess.Popen[str]]]:
    def secure(role: str) -> tuple[str, ...]:
        return ('--secure', str(keys / role)) if keys is not None else ()

    world = in_ns(hosts['world'], 'up', '--scenario', str(scenario), '--maps', '12', '--duration', duration,
                  '--listen', f'{SUBNET}.1', '--agents-here', str(here), '--out', str(tmp_path / 'world'),
                  *secure('world'), env=env, out=tmp_path / 'world.out')
    address = wait_for(tmp_path / 'world.out', r'--join (\S+)', world, 120).group(1)
    if refuse:  # ids the run does not leave to other hosts: one line, exit 2, while the run waits on
        wrong = subprocess.run(netns.cli(hosts['a'], 'agents', '--join', address, '--ids', '11-12',
                                         '--out', str(tmp_path / 'wrong')),
                               capture_output=True, text=True, env=env, timeout=120)
        assert wrong.returncode == 2 and wrong.stderr.strip().splitlines() == [
            'uav-flock: error: agents: --ids: MAP 12 is not one this run waits for from other hosts (it has 12 '
            'MAPs; 4-11 join from other hosts)'], wrong.stderr
    before_join(address)
    joined = [in_ns(hosts[role], 'agents', '--join', address, '--ids', ids, '--out', str(tmp_path / role),
                    *secure(role), env=env, out=tmp_path / f'{role}.out') for role, ids in (('a', a), ('b', b))]
    return world, joined


def end(procs: list[subprocess.Popen[str]]) -> None:
    for p in procs:
        if p.poll() is None:
            p.terminate()
    for p in procs:
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def test_a_run_over_three_hosts_equals_sim(hosts: dict[str, str], tmp_path: Path, ros_env: dict[str, str],
                                           paper_scenario_path: str) -> None:
    """... and what passes between the hosts names the run's topics and types in clear (DDS discovery over UDP):
    the control of the secure run's capture below."""
    scenario = small_scenario(paper_scenario_path, tmp_path)
    with captured(tmp_path / 'lan.raw', ros_env) as lan:
        world, joined = start(hosts, tmp_path, ros_env, scenario, '6', 4, '4-7', '8-11', refuse=True)
        try:
            assert world.wait(timeout=300) == 0, (tmp_path / 'world.out').read_text()
            for role, p in zip('ab', joined):
                assert p.wait(timeout=60) == 0, (tmp_path / f'{role}.out').read_text()
        finally:
            end([world, *joined])
    assert cli('sim', '--scenario', str(scenario), '--maps', '12', '--duration', '6',
               '--out', str(tmp_path / 'sim')).returncode == 0
    for name in ('trajectory.csv', 'metrics.csv'):
        assert (tmp_path / 'world' / name).read_bytes() == (tmp_path / 'sim' / name).read_bytes(), name
    assert sorted(p.name for p in (tmp_path / 'a' / 'logs').iterdir()) == [f'agents_{i}.log' for i in range(4, 8)]
    seen = lan.read_bytes()
    assert all(word in seen for word in IN_CLEAR), f'a plain run\'s discovery names its topics in clear ({len(seen)} bytes)'


def test_a_secure_run_over_three_hosts_equals_sim_and_strangers_neither_join_nor_steer(
        tmp_path: Path, ros_env: dict[str, str], paper_scenario_path: str) -> None:
    """`up --secure` and `agents --secure` over three hosts: TCP with TLS between every participant. Two more hosts
    on the LAN publish well-formed states of MAP 5 with a false position at every step, dialling the discovery server
    over TLS that checks nothing itself: one with no certificate, one with a certificate of another run's CA. Neither
    discovers the run nor is discovered, `up` names each once (and no member), the run equals `sim` byte for byte,
    and no topic or type name passes in clear. A third host dials the discovery server before the joining hosts do
    and says nothing, which stops the server accepting: `up` restarts it, and the joining hosts dial the new one."""
    from helpers.rogue import lax_profile
    from uav_flock_tools import keys, secure
    keys.make(tmp_path / 'keys', HOSTS)
    keys.make(tmp_path / 'other', ['otherca'])
    scenario = small_scenario(paper_scenario_path, tmp_path)
    strangers: list[subprocess.Popen[str]] = []
    with network(HOSTS + STRANGERS + [SILENT]) as hosts:
        with captured(tmp_path / 'lan.raw', ros_env) as lan:
            def silent(address: str) -> None:
                strangers.append(helper_in_ns(hosts[SILENT], 'silent', *address.rsplit(':', 1), env=ros_env))
            # 15 s, not 6: the strangers start once the world names its address, and a run over by then had
            # refused one stranger's handshakes and not yet the other's (once in three whole suites)
            world, joined = start(hosts, tmp_path, ros_env, scenario, '15', 4, '4-7', '8-11', keys=tmp_path / 'keys',
                                  before_join=silent)
            try:
                address = wait_for(tmp_path / 'world.out', r'--join (\S+)', world, 10).group(1)
                host, port = address.rsplit(':', 1)
                domain = str(int(port) - 11811)
                member = secure.profile(keys.check(tmp_path / 'other' / 'otherca'), 'client', (host, int(port)))
                for who in STRANGERS:
                    (tmp_path / f'{who}.xml').write_text(lax_profile(member, certificate=who == 'otherca'))
                strangers += [helper_in_ns(hosts[who], 'rogue', '5', '61', env={
                    **ros_env, 'ROS_DOMAIN_ID': domain, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET',
                    'FASTRTPS_DEFAULT_PROFILES_FILE': str(tmp_path / f'{who}.xml')}) for who in STRANGERS]
                assert ended(world, 300, tmp_path) == 0, (tmp_path / 'world.out').read_text()
                for role, p in zip('ab', joined):  # 120 s: under the whole suite's load, a joining host's four
                    # TLS participants once took over 60 s to go after the run ended (alone: under 15 s)
                    assert ended(p, 120, tmp_path) == 0, (tmp_path / f'{role}.out').read_text()
            finally:
                end([world, *joined])
                for p in strangers:
                    p.terminate()
                said = [p.communicate(timeout=30)[0] for p in strangers]
    said_up = (tmp_path / 'world.out').read_text()
    assert 'secured: TCP with TLS only' in said_up
    assert said[0].split() == ['closed', 'by', 'the', 'other', 'end'] and re.search(
        r'^uav-flock up: the discovery server stopped accepting connections for 5 s: restarted \(1\)', said_up, re.M), \
        f'the silent host said {said[0]!r}; up said: {said_up}'
    said = said[1:]
    named = re.findall(r'^uav-flock up: (\S+) was refused at the discovery server \d+ times', said_up, re.M)
    assert sorted(named) == [f'{SUBNET}.4', f'{SUBNET}.5'], f'each stranger named once, no member: {said_up}'
    for who, text in zip(STRANGERS, said):
        figures = re.search(r'^published (\d+) readers (\d+) nodes (\d+)$', text, re.M)
        assert figures, f'{who} said no figures: {text[-2000:]}'
        published, readers, nodes = (int(v) for v in figures.groups())
        assert published > 100 and readers == 0 and nodes == 0, f'{who}: {text[-2000:]}'
    assert cli('sim', '--scenario', str(scenario), '--maps', '12', '--duration', '15',
               '--out', str(tmp_path / 'sim')).returncode == 0
    for name in ('trajectory.csv', 'metrics.csv'):
        assert (tmp_path / 'world' / name).read_bytes() == (tmp_path / 'sim' / name).read_bytes(), name
    seen = lan.read_bytes()
    assert len(seen) > 100_000 and not any(word in seen for word in IN_CLEAR), \
        f'{len(seen)} bytes between the hosts: {[w for w in IN_CLEAR if w in seen]} in clear'


def test_losing_a_host_by_kill_and_by_link_leaves_the_exact_alive_count_and_the_rest_recovers(
        hosts: dict[str, str], tmp_path: Path, ros_env: dict[str, str], paper_scenario_path: str) -> None:
    # At t = 10 s host a's agents are killed and host b falls off the network at once: each is noticed when its
    # participants' lease ends (20 s in Fast DDS; lockstep waits for them), one wait for both, and the 8 left cover
    # the users again a few seconds later; the rest of the 100 s is margin for a slower machine.
    world, joined = start(hosts, tmp_path, ros_env, small_scenario(paper_scenario_path, tmp_path), '100', 8,
                          '8,9', '10,11')
    out = tmp_path / 'world.out'
    try:
        wait_for(out, r'^t = +10\.0 s', world, 180)
        killed = subprocess.run(netns.cli(hosts['a'], 'kill', '--run', str(tmp_path / 'a'), '--ids', '8,9'),
                                capture_output=True, text=True, env=ros_env)
        assert killed.returncode == 0, killed.stderr
        # No pid of host a is known here: DDS says when its participants are gone (their lease ends).
        netns.ip('-n', hosts['b'], 'link', 'set', 'eth0', 'down')  # host b falls off the network, its agents live on
        cut = time.monotonic()
        wait_for(out, r'alive = 8 ', world, 90)
        print(f'hosts a and b dropped {time.monotonic() - cut:.1f} s after the kill and the link went down')
        assert world.wait(timeout=300) == 0, out.read_text()
    finally:
        end([world, *joined])
    metrics = [line.split(',') for line in (tmp_path / 'world' / 'metrics.csv').read_text().splitlines()[1:]]
    alive = [int(float(row[4])) for row in metrics]
    # Each agent process is its own DDS participant: the two of a host may be dropped a step apart.
    dropped = sorted(int(i) for ids in re.findall(r'dropped MAPs \[([\d, ]+)\]', out.read_text())
                     for i in ids.split(','))
    assert dropped == [8, 9, 10, 11], f'exactly the MAPs of hosts a and b were dropped: {dropped}'
    assert alive[0] == 12 and alive[-1] == 8 and all(a >= b for a, b in zip(alive, alive[1:]))
    rc = float(metrics[-1][2])
    assert rc >= 0.95, f'the 8 MAPs left cover the users again: R_c {rc:.3f} at the end'
