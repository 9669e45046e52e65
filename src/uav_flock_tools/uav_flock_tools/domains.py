"""A run's ROS_DOMAIN_ID (claimed, so that runs on one host never hear each other), its environment and its
discovery: simple discovery on this host, or a Fast DDS discovery server for the run.

Fast DDS is told to use UDP only, with large socket buffers; rmw_fastrtps overrides that with its own
transports (loopback UDP and shared memory) when discovery is LOCALHOST (docs/design.md).
"""
from __future__ import annotations

import fcntl
import os
import random
import signal
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import Optional

from . import strangers
from .spawn import dies_with_parent, stop

DISCOVERY_BASE_PORT = 11811  # a run's discovery server listens on this port plus its domain


# Socket buffers of a run's participants (discovery server or subnet; LOCALHOST discovery keeps rmw's own
# transports). The kernel's default (208 KiB) overflows when a hundred nodes subscribe at once, and
# reliable DDS then spends its time repairing dropped datagrams.
SOCKET_BUFFER_BYTES = 4 * 1024 * 1024


def ros_env(domain_id: int, discovery_server: Optional[str] = None, discovery_range: str = 'LOCALHOST'
            ) -> dict[str, str]:
    """Environment of a run's processes: its own domain, and its discovery server if it has one."""
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(domain_id), FASTDDS_BUILTIN_TRANSPORTS=f'UDPv4?sockets_size={SOCKET_BUFFER_BYTES}',
               PYTHONUNBUFFERED='1')
    if discovery_server:
        env['ROS_DISCOVERY_SERVER'] = discovery_server
        env.pop('ROS_AUTOMATIC_DISCOVERY_RANGE', None)
    else:
        env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = discovery_range
        env.pop('ROS_DISCOVERY_SERVER', None)
    return env


def adopt(env: dict[str, str]) -> None:
    """This process's own environment made exactly env, for the participants it creates: a key env lacks goes
    too (ROS_DISCOVERY_SERVER from the user's shell would otherwise outlive a secured run's profile)."""
    for key in set(os.environ) - set(env):
        del os.environ[key]
    os.environ.update(env)


def discovery_server_address(domain_id: int, host: str = '127.0.0.1') -> str:
    """One port per domain, so that runs in different domains each have their own server."""
    return f'{host}:{DISCOVERY_BASE_PORT + domain_id}'


class DiscoveryServer:
    """The Fast DDS discovery server the wheels ship, on address (host:port, UDP), in its own session; or as the
    XML profile says (secure.profile: TCP with TLS), and then a host refused at its handshake is named on the
    terminal once, for as long as the server runs (strangers.py: Fast DDS logs nothing of it), and a server that
    stopped accepting is restarted on the same port (strangers.STALLED_S), said on the terminal and in its log."""

    def __init__(self, address: str, env: dict[str, str], log: Path, profile: Optional[Path] = None) -> None:
        from .secure import environment
        host, port = address.rsplit(':', 1)
        self.args = ['-x', str(profile)] if profile is not None else ['-i', '0', '-l', host, '-p', port]
        self.env, self.log, self.restarts = environment(env, profile), log, 0
        self._lock, self._retired = threading.Lock(), False
        self.proc = self._start('w')
        if profile is not None:
            strangers.watch(int(port), lambda: not self._retired and self.proc.poll() is None,
                            lambda line: print(f'uav-flock up: {line}', flush=True), self.restart)

    def _start(self, mode: str) -> subprocess.Popen:
        with open(self.log, mode) as out:
            return subprocess.Popen(['fast-discovery-server', *self.args],
                                    env=self.env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True,
                                    preexec_fn=dies_with_parent(signal.SIGTERM))

    def restart(self) -> None:
        """The server anew on its port, unless it is being stopped: what was stalling it ends with the old one."""
        with self._lock:
            if self._retired or self.proc.poll() is not None:
                return
            self.proc.kill()
            self.proc.wait()
            self.restarts += 1
            with open(self.log, 'a') as out:
                out.write(f'--- restarted ({self.restarts}): it had stopped accepting connections\n')
            self.proc = self._start('a')
        print(f'uav-flock up: the discovery server stopped accepting connections for {strangers.STALLED_S:g} s: '
              f'restarted ({self.restarts}); its clients dial it again', flush=True)

    def stop(self) -> None:
        """No restart from now on, and the server ended (spawn.stop)."""
        with self._lock:
            self._retired = True
        stop([self.proc])


# Domains a run may be given: 0, ROS's default, is left to whatever else runs ROS on the host. Above 101
# Fast DDS's ports for a domain run into Linux's ephemeral range.
FRESH_DOMAINS = range(1, 102)
DOMAIN_CLAIMS = Path(tempfile.gettempdir()) / 'uav-flock-domains'


class DomainInUse(Exception):
    """Every domain asked for is held by another run on this host."""


class DomainClaim:
    """A ROS_DOMAIN_ID held for one run, released on release(), on leaving a with block, or when the process ends.

    Two runs in one domain would hear each other's MAPs: their topics have the same names. The claim is
    an flock on one file per domain, which the kernel drops with the process, so a SIGKILLed run frees
    its domain at once and nothing stale is left to clean. The file's mtime is the domain's last use.
    """

    def __init__(self, domain: int, fd: int) -> None:
        self.domain, self._fd = domain, fd

    def release(self) -> None:
        if self._fd >= 0:
            _mark_used(self._fd)
            os.close(self._fd)
            self._fd = -1

    def __enter__(self) -> int:
        return self.domain

    def __exit__(self, *exc: object) -> None:
        self.release()


def _mark_used(fd: int) -> None:
    """Date the claim file now, to the nanosecond given: a file's own "now" follows the kernel's coarse
    clock (milliseconds), and claims made within one tick would tie."""
    now = time.time_ns()
    try:
        os.utime(fd, ns=(now, now))
    except PermissionError:
        pass  # another user's claim file: the claim holds, its date stays theirs


def last_used(domain: int) -> int:
    """When a run last claimed or released the domain, in ns (0 if never on this host)."""
    try:
        return (DOMAIN_CLAIMS / str(domain)).stat().st_mtime_ns
    except FileNotFoundError:
        return 0


def claim_domain(requested: Optional[int] = None) -> DomainClaim:
    """The requested domain, or the free one of FRESH_DOMAINS least recently used; DomainInUse if another run
    holds it.

    Least recently used, not merely free: the participants of a run that was SIGKILLed stay in the
    domain's discovery until their lease runs out (20 s in Fast DDS), and a new run there would see
    their endpoints, e.g. subscriptions of MAPs that no longer exist.
    """
    if not DOMAIN_CLAIMS.is_dir():
        DOMAIN_CLAIMS.mkdir(exist_ok=True)
        os.chmod(DOMAIN_CLAIMS, 0o1777)  # shared by every user of the host, as DDS domains are
    if requested is not None:
        candidates = [requested]
    else:
        shuffled = random.SystemRandom().sample(FRESH_DOMAINS, len(FRESH_DOMAINS))  # ties: never used
        candidates = sorted(shuffled, key=last_used)
    for domain in candidates:
        fd = os.open(DOMAIN_CLAIMS / str(domain), os.O_RDONLY | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            continue
        _mark_used(fd)
        return DomainClaim(domain, fd)
    if requested is not None:
        raise DomainInUse(f'ROS_DOMAIN_ID {requested} is in use by another run on this host')
    raise DomainInUse(f'every ROS_DOMAIN_ID from {FRESH_DOMAINS[0]} to {FRESH_DOMAINS[-1]} is in use by '
                      'another run on this host')
