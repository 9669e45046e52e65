"""Hosts on one machine: Linux network namespaces joined by veth pairs on a bridge (needs root).

Each host has its own network stack, loopback and address, so processes in two of them talk only over
the veth link, as two machines do over a LAN. The bridge lives in a namespace of its own, so nothing of
the machine's own network is touched; `hosts` removes every namespace it made (their links go with
them), also when the block inside fails. The multi-host test and benchmark use it.
"""
from __future__ import annotations

import os
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator


class NetnsError(Exception):
    """Namespaces cannot be made here (not root, no `ip`), or an `ip` command failed."""


def ip(*args: str) -> None:
    try:
        done = subprocess.run(['ip', *args], capture_output=True, text=True)
    except FileNotFoundError:
        raise NetnsError('the `ip` command (iproute2) is missing') from None
    if done.returncode != 0:
        raise NetnsError(f'ip {" ".join(args)}: {done.stderr.strip()}')


def _tag() -> str:
    return f'uavf{os.getpid() % 100000}'


def bridge() -> str:
    """The namespace holding the bridge of this process's hosts; its port p<i> leads to the i-th host."""
    return f'{_tag()}br'


@contextmanager
def hosts(roles: list[str], subnet: str) -> Iterator[dict[str, str]]:
    """{role: namespace}, the i-th role at address <subnet>.<i> on interface eth0 (subnet like 10.231.7),
    counted from 1."""
    if os.geteuid() != 0:
        raise NetnsError('network namespaces (ip netns add) need root')
    names = {role: f'{_tag()}{role}'[:15] for role in roles}
    made: list[str] = []
    try:
        ip('netns', 'add', bridge())
        made.append(bridge())
        ip('-n', bridge(), 'link', 'add', 'br0', 'type', 'bridge')
        ip('-n', bridge(), 'link', 'set', 'br0', 'up')
        for n, role in enumerate(roles, 1):
            ns = names[role]
            ip('netns', 'add', ns)
            made.append(ns)
            ip('-n', ns, 'link', 'set', 'lo', 'up')
            ip('-n', ns, 'link', 'add', 'eth0', 'type', 'veth', 'peer', 'name', f'p{n}', 'netns', bridge())
            ip('-n', bridge(), 'link', 'set', f'p{n}', 'master', 'br0', 'up')
            ip('-n', ns, 'addr', 'add', f'{subnet}.{n}/24', 'dev', 'eth0')
            ip('-n', ns, 'link', 'set', 'eth0', 'up')
        yield names
    finally:
        for ns in reversed(made):
            subprocess.run(['ip', 'netns', 'del', ns], capture_output=True)


def cli(ns: str, *args: str) -> list[str]:
    """The command line of `uav-flock ARGS` run in host ns (this interpreter, this environment)."""
    return ['ip', 'netns', 'exec', ns, sys.executable, '-m', 'uav_flock_tools.cli', *args]


def counter(ns: str, interface: str, name: str) -> int:
    """An interface statistic (rx_bytes, tx_bytes, ...) as the namespace sees it."""
    done = subprocess.run(['ip', 'netns', 'exec', ns, 'cat', f'/sys/class/net/{interface}/statistics/{name}'],
                          capture_output=True, text=True)
    if done.returncode != 0:
        raise NetnsError(f'{ns}: no counter {interface}/{name}: {done.stderr.strip()}')
    return int(done.stdout)


def pids(ns: str) -> list[int]:
    """The processes running in a namespace (`ip netns pids`)."""
    done = subprocess.run(['ip', 'netns', 'pids', ns], capture_output=True, text=True)
    return [int(p) for p in done.stdout.split()]


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of one process so far (0 once it is gone)."""
    try:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except (OSError, IndexError):
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
