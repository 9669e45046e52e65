"""Hosts refused at a secured run's discovery server, named once on the listening side (`up --listen --secure`), and
a server that stopped accepting, restarted.

Fast DDS 2.14 logs nothing when a TLS handshake on a connection it accepted fails: it closes the connection,
and the dialler tries again some 5 s later. The kernel's socket table shows it all the same. A member's
connection to the discovery server stays established for the whole run; a refused one is closed by the
server within a fraction of a second (tried: ESTABLISHED for 0.1-0.2 s, then FIN_WAIT2 and TIME_WAIT, every
5 s). So an address whose connections to the server's port end short, REFUSED_TIMES of them (some 5 s), none
having held for HELD_S, is named; an address that ever held one is a member (one host's members and strangers share an
address, and such a stranger is not told apart). The table is read from /proc/net/tcp and tcp6 of the
process's own network namespace: no privileges, no packets.

Fast DDS 2.14 accepts the next connection only once the last one's TLS handshake has ended, and a handshake has no
deadline: one connection that sends nothing (`nc HOST PORT` from anywhere on the LAN, or a dialler that stalls)
stops the server accepting for as long as it is open, and no participant that dials later is discovered (tried:
no MAP of 8 seen for 90 s, the run went on within a second of that connection closing). The listener's own row of
the table shows it: its receive queue is its backlog of connections the server has not taken. A backlog that stays
for STALLED_S, never shrinking, is a stalled server; `up` restarts it (domains.DiscoveryServer), the stalling connection dies with
it and the clients dial the new one.
"""
from __future__ import annotations

import ipaddress
import threading
import time
from pathlib import Path
from typing import Callable, Iterable, Iterator, NamedTuple, Optional

HELD_S = 2.0          # a connection established this long was let in: its address is a member's
REFUSED_TIMES = 2     # connections ended short before an address is named (a member's first dial may be reset)
POLL_S = 0.5          # the socket table is read this often (a refused connection's TIME_WAIT lasts 60 s)
STALLED_S = 5.0      # a backlog that stays this long: the server is not accepting (one handshake takes milliseconds)
ESTABLISHED, LISTEN = 0x01, 0x0A
TABLES = (Path('/proc/net/tcp'), Path('/proc/net/tcp6'))


class Peer(NamedTuple):
    """One connection to the watched port, as the socket table shows it."""

    address: str
    port: int
    established: bool


def _address(hex_address: str) -> str:
    """An address of /proc/net/tcp{,6} (32-bit words in host byte order, little-endian here) as text."""
    raw = bytes.fromhex(hex_address)
    words = b''.join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4))
    ip = ipaddress.ip_address(words)
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    return str(ip)


def _rows(lines: Iterable[str], port: int) -> Iterator[list[str]]:
    """The fields of each row of a socket table whose local end is `port` (the header skipped)."""
    for line in lines:
        fields = line.split()
        if len(fields) >= 10 and fields[0].endswith(':') and int(fields[1].rsplit(':', 1)[1], 16) == port:
            yield fields


def peers(lines: Iterable[str], port: int) -> list[Peer]:
    """The connections whose local end is `port`, from the lines of a socket table (the listener skipped, and
    connections the listener has not accepted yet: established, no inode; a member kept waiting in the backlog of a
    stalled server has neither held a connection nor been refused)."""
    out = []
    for fields in _rows(lines, port):
        remote, state = fields[2], int(fields[3], 16)
        if state == LISTEN or (state == ESTABLISHED and fields[9] == '0'):
            continue
        address, remote_port = remote.rsplit(':', 1)
        out.append(Peer(_address(address), int(remote_port, 16), state == ESTABLISHED))
    return out


class Refusals:
    """What the socket table has shown of the watched port so far: which addresses to name, each once."""

    def __init__(self, held_s: float = HELD_S, times: int = REFUSED_TIMES) -> None:
        self.held_s, self.times = held_s, times
        self.first: dict[tuple[str, int], float] = {}   # a connection: when first seen established
        self.last: dict[tuple[str, int], float] = {}    # and when last
        self.ended: dict[str, set[int]] = {}            # an address: its connections that ended short
        self.members: set[str] = set()
        self.named: set[str] = set()

    def see(self, now: float, table: list[Peer]) -> list[str]:
        """The addresses to name after this reading of the table (never one named before, nor a member's)."""
        for peer in table:
            key = (peer.address, peer.port)
            if peer.established:
                self.last[key] = now
                if now - self.first.setdefault(key, now) >= self.held_s:
                    self.members.add(peer.address)
            elif self.last.get(key, 0.0) - self.first.get(key, 0.0) < self.held_s:  # ended, or ending, before it held
                self.ended.setdefault(peer.address, set()).add(peer.port)
        new = sorted(a for a, ports in self.ended.items()
                     if len(ports) >= self.times and a not in self.members and a not in self.named)
        self.named.update(new)
        return new


def backlog(lines: Iterable[str], port: int) -> int:
    """Connections to `port` that its listener has not accepted yet (the LISTEN row's receive queue), from the lines
    of a socket table."""
    return sum(int(f[4].split(':')[1], 16) for f in _rows(lines, port) if int(f[3], 16) == LISTEN)


class Stall:
    """Whether the listener's backlog has stayed for stalled_s without shrinking: a busy server that takes its
    connections slowly shrinks it now and then, a stalled one never does."""

    def __init__(self, stalled_s: float = STALLED_S) -> None:
        self.stalled_s = stalled_s
        self.since: Optional[float] = None
        self.last = 0

    def see(self, now: float, waiting: int) -> bool:
        if not waiting or waiting < self.last:
            self.since = None
        self.last = waiting
        if not waiting:
            return False
        self.since = now if self.since is None else self.since
        if now - self.since < self.stalled_s:
            return False
        self.since, self.last = None, 0  # a new server starts with a clean count
        return True


def _lines() -> list[str]:
    lines: list[str] = []
    for table in TABLES:
        try:
            lines += table.read_text().splitlines()
        except OSError:  # no IPv6, or no /proc: nothing to name
            pass
    return lines


def read_tables(port: int) -> list[Peer]:
    """The connections to `port` in this network namespace, IPv4 and IPv6."""
    return peers(_lines(), port)


def watch(port: int, running: Callable[[], bool], say: Callable[[str], None],
          stalled: Callable[[], None] = lambda: None) -> threading.Thread:
    """Read the socket table every POLL_S while running(): say one line for each address refused, and call stalled()
    each time the listener's backlog has stayed STALLED_S."""
    def loop() -> None:
        seen, stall = Refusals(), Stall()
        while running():
            lines, now = _lines(), time.monotonic()
            for address in seen.see(now, peers(lines, port)):
                say(f'{address} was refused at the discovery server {len(seen.ended[address])} times (a failed TLS '
                    f'handshake: no certificate of this run\'s CA?); the run goes on without it')
            if stall.see(now, backlog(lines, port)):
                stalled()
            time.sleep(POLL_S)
    thread = threading.Thread(target=loop, name='strangers', daemon=True)
    thread.start()
    return thread
