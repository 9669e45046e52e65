"""The live view: `up --view` serves a running formation over the Foxglove WebSocket protocol.

The client here is a plain WebSocket client speaking `foxglove.sdk.v1` (the protocol's spec: a JSON
`advertise` names each channel with its schema; a JSON `subscribe` asks for one; each message then comes
as a binary frame: opcode 1, subscription id (u32), log time (u64, ns), payload). It decodes the scene with
the schema the server advertised, through the mcap library's protobuf decoder, nothing of our own.
"""
from __future__ import annotations

import asyncio
import base64
import json
import signal
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from helpers.runs import cli, up, wait_for_line
from world_sim.core.records import read_csv

SUBPROTOCOL = 'foxglove.sdk.v1'
DT = 0.1  # s, the shipped scenarios' step
GOLDEN = Path(__file__).resolve().parents[1] / 'golden' / 'bag'
MESSAGE_DATA = 1  # opcode of a binary server message carrying a channel's message


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return int(s.getsockname()[1])


async def watch(port: int, frames: int, subprotocol: str = SUBPROTOCOL) -> tuple[dict[str, dict], list[tuple[int, bytes]]]:
    """Connect (retrying while the run starts), note the advertised channels, subscribe to /scene and take
    `frames` of its messages: (log time in ns, payload)."""
    import websockets

    give_up = time.monotonic() + 90.0
    while True:
        try:
            ws = await websockets.connect(f'ws://127.0.0.1:{port}', subprotocols=[subprotocol])
            break
        except OSError:
            if time.monotonic() > give_up:
                raise AssertionError(f'nothing served on port {port} within 90 s of `up --view`') from None
            await asyncio.sleep(0.3)
    async with ws:
        assert ws.subprotocol == subprotocol
        channels: dict[str, dict] = {}
        while not {'/scene', '/metrics'} <= set(channels):
            msg = await asyncio.wait_for(ws.recv(), 30)
            if isinstance(msg, str) and json.loads(msg)['op'] == 'advertise':
                channels.update({c['topic']: c for c in json.loads(msg)['channels']})
        await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [{'id': 7, 'channelId': channels['/scene']['id']}]}))
        got: list[tuple[int, bytes]] = []
        while len(got) < frames:
            msg = await asyncio.wait_for(ws.recv(), 30)
            if isinstance(msg, bytes) and msg[0] == MESSAGE_DATA:  # (a recording's server also sends its time)
                _, sub, ns = struct.unpack_from('<BIQ', msg)
                assert sub == 7
                got.append((ns, msg[13:]))
    return channels, got


def test_up_view_serves_the_scene_and_metrics_with_the_worlds_positions(tmp_path: Path) -> None:
    from mcap.records import Schema
    from mcap_protobuf.decoder import DecoderFactory

    port, run = free_port(), tmp_path / 'run'
    proc = up('--maps', '6', '--duration', '12', '--sync', 'realtime', '--view', str(port), '--out', str(run))
    try:
        channels, got = asyncio.run(watch(port, 20))
        out, _ = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 0, out
    assert f'live view on ws://localhost:{port}' in out
    assert (channels['/scene']['schemaName'], channels['/scene']['encoding']) == ('foxglove.SceneUpdate', 'protobuf')
    assert (channels['/metrics']['schemaName'], channels['/metrics']['encoding']) == ('uav_flock.Metrics', 'json')
    assert 'coverage_ratio' in json.loads(channels['/metrics']['schema'])['properties']
    c = channels['/scene']
    decode = DecoderFactory().decoder_for('protobuf', Schema(id=1, name=c['schemaName'], encoding=c['schemaEncoding'],
                                                            data=base64.b64decode(c['schema'])))
    assert decode is not None
    traj = read_csv(run / 'trajectory.csv')
    checked = 0
    for ns, payload in got:
        update = decode(payload)
        spheres = {e.id: e.spheres[0].pose.position for e in update.entities if e.id.startswith('map_')}
        at_step = np.flatnonzero(traj['step'] == round(ns / 1e9 / DT))
        assert set(spheres) == {f'map_{int(i)}' for i in traj['id'][at_step]}, f'the MAPs flying at t = {ns / 1e9} s'
        for n in at_step:
            at = spheres[f'map_{int(traj["id"][n])}']
            assert (at.x, at.y, at.z) == (traj['x'][n], traj['y'][n], traj['z'][n]), \
                f'MAP {int(traj["id"][n])} at t = {ns / 1e9} s'
        checked += 1
    assert checked == len(got) == 20


def test_view_plays_a_recorded_run_into_the_same_server(tmp_path: Path) -> None:
    """`view BAG` serves the recording with the live view's channels, its spheres where the bag's MAPs were."""
    from mcap.records import Schema
    from mcap_protobuf.decoder import DecoderFactory
    from uav_flock_tools import bag

    port = free_port()
    proc = subprocess.Popen([sys.executable, '-m', 'uav_flock_tools.cli', 'view', str(GOLDEN), '--port', str(port),
                             '--rate', '2'], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        wait_for_line(proc, 'Waiting for a client', 60)
        time.sleep(3.0)  # a user who connects a while after starting it still sees the run from its start
        channels, got = asyncio.run(watch(port, 10))
        seen = wait_for_line(proc, 'left', 30)
        seen += wait_for_line(proc, 'holding the last frame', 30)
        assert proc.poll() is None, 'it serves on until Ctrl-C'
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
    finally:
        proc.kill()
    out = ''.join(seen) + out
    assert proc.returncode == 0 and 'frames played' in out and 'Traceback' not in out, out
    assert 'view: client 1 connected' in out and 'view: client 1 left' in out, out
    assert got[0][0] == 0, f'the first frame a late client sees is t = 0, not {got[0][0] / 1e9} s'
    c = channels['/scene']
    decode = DecoderFactory().decoder_for('protobuf', Schema(id=1, name=c['schemaName'], encoding=c['schemaEncoding'],
                                                            data=base64.b64decode(c['schema'])))
    traj = bag.load(GOLDEN).trajectory
    for ns, payload in got:
        spheres = {e.id: e.spheres[0].pose.position for e in decode(payload).entities if e.id.startswith('map_')}
        rows = traj[traj[:, 0] == round(ns / 1e9 / DT)]
        assert {f'map_{int(i)}': (x, y, z) for i, x, y, z in rows[:, 2:6]} == \
            {k: (p.x, p.y, p.z) for k, p in spheres.items()}


def test_view_speaks_both_names_of_the_protocol_and_says_why_it_refuses_a_client(tmp_path: Path) -> None:
    """Older Lichtblick releases offer `foxglove.websocket.v1`; a client offering neither name hears why."""
    import websockets
    port = free_port()
    proc = subprocess.Popen([sys.executable, '-m', 'uav_flock_tools.cli', 'view', str(GOLDEN), '--port', str(port),
                             '--loop'], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        wait_for_line(proc, 'Waiting for a client', 60)
        for name in ('foxglove.websocket.v1', SUBPROTOCOL):
            channels, got = asyncio.run(watch(port, 2, name))
            assert {'/scene', '/metrics'} <= set(channels) and len(got) == 2, name

        async def stranger() -> int:
            try:
                async with websockets.connect(f'ws://127.0.0.1:{port}', subprotocols=['ros.bridge.v2']):
                    return 101
            except websockets.exceptions.InvalidStatus as exc:
                return exc.response.status_code
        assert asyncio.run(stranger()) == 400
        seen = ''.join(wait_for_line(proc, 'refused a client', 30))
    finally:
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
    refused = [line for line in (seen + out).splitlines() if 'refused' in line]
    assert refused == ['view: refused a client at 127.0.0.1: it offered ros.bridge.v2; the view speaks '
                       'foxglove.sdk.v1 or foxglove.websocket.v1'], seen + out


def test_view_of_a_folder_that_is_no_bag_is_one_line_and_exit_2(tmp_path: Path) -> None:
    done = cli('view', str(tmp_path))
    assert done.returncode == 2 and done.stderr.count('\n') == 1 and 'not a rosbag2 bag' in done.stderr, done.stderr


def test_view_on_a_port_in_use_is_one_line_and_exit_2(tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(('127.0.0.1', 0))
        taken.listen()
        port = taken.getsockname()[1]
        done = cli('up', '--maps', '3', '--duration', '1', '--view', str(port), '--out', str(tmp_path / 'run'))
    assert done.returncode == 2 and done.stderr.count('\n') == 1 and 'in use' in done.stderr, done.stderr
    assert not (tmp_path / 'run').exists(), 'nothing is left behind by a refused run'


def test_a_port_taken_once_the_run_started_is_said_on_the_terminal_and_the_run_goes_on(tmp_path: Path) -> None:
    """`up` finds the port free, then another program binds it before the viewer does: one line says the view
    is not served and why, and the run ends as it would have."""
    port, run = free_port(), tmp_path / 'run'
    proc = up('--maps', '3', '--duration', '3', '--sync', 'realtime', '--view', str(port), '--out', str(run))
    try:
        seen = wait_for_line(proc, 'MAPs in', 120)  # the port was checked; the viewer is still starting
        with socket.socket() as taken:
            taken.bind(('127.0.0.1', port))
            taken.listen()
            out, _ = proc.communicate(timeout=180)
    finally:
        proc.kill()
    out = ''.join(seen) + out
    assert proc.returncode == 0, out
    said = [line for line in out.splitlines() if 'live view' in line]
    assert len(said) == 1 and 'the live view is not served' in said[0] and str(port) in said[0], out
    assert 'Traceback' not in out and (run / 'metrics.csv').exists(), out


@pytest.mark.parametrize('args', [('--view', '0'), ('--view', 'x')])
def test_view_takes_a_port_number(tmp_path: Path, args: tuple[str, str]) -> None:
    done = cli('up', '--maps', '3', '--duration', '1', *args, '--out', str(tmp_path / 'run'))
    assert done.returncode == 2 and done.stderr.strip().count('\n') <= 1 and '--view' in done.stderr, done.stderr
