"""Hosts refused at a secured run's discovery server, and a server that stopped accepting
(uav_flock_tools/strangers.py): the kernel's socket table as it reads it, over real sockets, which addresses it names
and when it calls a server stalled."""
from __future__ import annotations

import socket
import time
from pathlib import Path

from uav_flock_tools.strangers import Peer, Refusals, Stall, backlog, read_tables


def test_the_socket_table_shows_a_connection_held_and_then_closed_by_the_listening_side() -> None:
    with socket.create_server(('127.0.0.1', 0)) as server:
        port = server.getsockname()[1]
        client = socket.create_connection(('127.0.0.1', port))
        accepted, _ = server.accept()
        mine = client.getsockname()[1]
        assert Peer('127.0.0.1', mine, True) in read_tables(port)
        accepted.close()  # the listening side ends it first, as Fast DDS does after a failed handshake
        time.sleep(0.1)
        after = [p for p in read_tables(port) if p.port == mine]
        client.close()
    assert after and not any(p.established for p in after), after
    assert all(p.port != port for p in read_tables(port)), 'the listener itself is no peer'


def test_an_address_is_named_once_after_its_dials_end_short_and_never_if_one_held() -> None:
    seen = Refusals(held_s=2.0, times=2)
    member, stranger = '10.0.0.2', '10.0.0.9'
    assert seen.see(0.0, [Peer(member, 40000, False), Peer(stranger, 50000, True)]) == []  # a member's first dial reset
    assert seen.see(0.5, [Peer(member, 40001, True), Peer(stranger, 50000, False)]) == []  # one refusal is not enough
    assert seen.see(3.0, [Peer(member, 40001, True), Peer(stranger, 50001, True)]) == []
    assert seen.see(3.5, [Peer(member, 40001, True), Peer(stranger, 50001, False), Peer(member, 40002, False)]) == \
        [stranger], 'the stranger was refused twice; the member held a connection for 3 s'
    assert seen.see(9.0, [Peer(stranger, 50002, False), Peer(stranger, 50003, False)]) == [], 'named once'
    late = Refusals(held_s=2.0, times=2)
    assert late.see(0.0, [Peer(member, 1, True)]) == [] and late.see(2.5, [Peer(member, 1, True)]) == []
    assert late.see(3.0, [Peer(member, 1, False), Peer(member, 2, False), Peer(member, 3, False)]) == [], \
        'an address that held a connection is a member\'s, whatever its other dials do'
    unseen = Refusals(held_s=2.0, times=2)
    assert unseen.see(0.0, [Peer(stranger, 7, True)]) == [] and \
        unseen.see(0.5, [Peer(stranger, 7, False), Peer(stranger, 8, False)]) == [stranger], \
        'a connection seen established once and then closing did not hold; one first seen closing neither'


def test_the_listeners_backlog_counts_connections_it_has_not_accepted_and_they_are_no_peers_yet() -> None:
    with socket.create_server(('127.0.0.1', 0), backlog=8) as server:
        port = server.getsockname()[1]
        table = Path('/proc/net/tcp')
        assert backlog(table.read_text().splitlines(), port) == 0
        clients = [socket.create_connection(('127.0.0.1', port)) for _ in range(2)]
        time.sleep(0.05)
        waiting, unseen = backlog(table.read_text().splitlines(), port), read_tables(port)
        accepted, _ = server.accept()
        after, seen = backlog(table.read_text().splitlines(), port), read_tables(port)
        for c in (*clients, accepted):
            c.close()
    assert (waiting, after) == (2, 1)
    assert unseen == [] and len(seen) == 1 and seen[0].established, \
        'a connection waiting in the backlog is no peer yet: it has neither held nor been refused'


def test_a_backlog_is_a_stall_once_it_has_stayed_stalled_s_without_shrinking() -> None:
    stall = Stall(stalled_s=5.0)
    assert [stall.see(t, 1) for t in (0.0, 2.0, 4.9)] == [False, False, False]
    assert stall.see(5.0, 2), 'waiting since 0 s, never fewer'
    assert not stall.see(5.5, 1), 'counted anew after a stall was called'
    assert not stall.see(9.0, 0) and not stall.see(9.5, 1) and not stall.see(14.0, 1), 'it emptied at 9 s'
    assert stall.see(14.5, 1)
    busy = Stall(stalled_s=5.0)
    assert not any(busy.see(t, w) for t, w in ((0.0, 3), (2.0, 5), (4.0, 4), (6.0, 6), (8.5, 6))), \
        'a backlog that shrank at 4 s is a busy server: counted from then'
    assert busy.see(9.0, 7)
