"""`view BAG`: a recorded run served to the live view's clients at its recorded pace (no ROS needed).

Foxglove or Lichtblick connect to it exactly as to `up --view`, and see the same channels (scene.py). It
serves until Ctrl-C: it waits for the first client before it plays, so that nobody misses the start, plays
the run, then holds the last frame for clients that come later (or plays the run again, with loop).
"""
from __future__ import annotations

import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable

from world_sim.core import records

from . import bag, report, scene

HOLD_PERIOD_S = 1.0  # the last frame is sent again this often while held, for a client that connects late


class Clients:
    """Who is watching: a client counts from its first subscription to its last one ending (or leaving).

    The Foxglove SDK tells of subscriptions, not of connections; a client subscribes to the channels its
    layout shows as soon as it connects. Called from the server's thread.
    """

    def __init__(self, said: Callable[[str], None]) -> None:
        self.said = said
        self.lock = threading.Lock()
        self.watching: dict[int, set[int]] = {}
        self.first = threading.Event()

    def on_subscribe(self, client: Any, channel: Any) -> None:
        with self.lock:
            new = client.id not in self.watching
            self.watching.setdefault(client.id, set()).add(channel.id)
        if new:
            self.said(f'view: client {client.id} connected')
            self.first.set()

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        with self.lock:
            channels = self.watching.get(client.id)
            if channels is None:
                return
            channels.discard(channel.id)
            gone = not channels
            if gone:
                del self.watching[client.id]
        if gone:
            self.said(f'view: client {client.id} left')


_SAYING = threading.Lock()


def say(line: str) -> None:
    """One whole line as it happens, also into a pipe. The gate's thread and the server's callbacks both speak:
    print writes a line and its newline apart, and two threads' lines came out run together."""
    with _SAYING:
        sys.stdout.write(line + '\n')
        sys.stdout.flush()


def play(path: Path, port: int, rate: float = 1.0, loop: bool = False, said: Callable[[str], None] = say) -> int:
    """Serve the bag's frames on ws://localhost:port, t seconds of the run at t / rate seconds of the wall
    clock, once a client is there, until Ctrl-C; returns how many frames went out. ValueError if the port
    cannot be served."""
    import foxglove

    from . import gate
    run = bag.load(path)
    bag.summary(run)  # a bag without /metrics is refused here, with its reason
    traj = records.columns(run.trajectory)
    clients = Clients(said)
    t, update, figures = 0.0, None, None  # the last frame played, which is held
    try:
        server = gate.start_server(said, host='127.0.0.1', port=port, name='uav-flock', server_listener=clients,
                                   capabilities=[foxglove.Capability.Time])  # the recording's clock
    except RuntimeError as exc:
        raise ValueError(f'--port {port}: cannot serve there ({exc})') from None
    channels, sent = scene.Channels(), 0  # advertised now, so that a client finds them when it connects
    said(f'view: serving {path} on ws://localhost:{server.port}: in Foxglove (or Lichtblick), Open connection, '
         'Foxglove WebSocket, that URL; docs/foxglove_layout.json lays out the 3-D scene and the plots. Waiting '
         'for a client before playing; Ctrl-C ends')
    with Interrupt() as stop:
        try:
            while not clients.first.is_set() and not stop.pause(0.5):
                pass
            while not stop.asked:
                said(f'view: playing {run.metrics[-1, 1]:.1f} s of the run at x{rate:g}')
                began = time.monotonic()
                for t, update, figures, logs in report.scene_frames(run, traj):
                    if stop.pause(began + t / rate - time.monotonic()):
                        break
                    server.broadcast_time(scene.nanoseconds(t))
                    channels.frame(t, update, figures, logs)
                    sent += 1
                if not loop:
                    break
            if not stop.asked:
                said('view: played to the end; holding the last frame (Ctrl-C ends)')
            while not stop.pause(HOLD_PERIOD_S):
                server.broadcast_time(scene.nanoseconds(t))
                if update is not None:
                    channels.frame(t, update, figures, [])
        finally:
            server.stop()
    return sent


class Interrupt:
    """Ctrl-C (or SIGTERM) as a flag that the serving loops read, how a served view ends.

    A KeyboardInterrupt raised by Python's own handler can land inside the Foxglove server's native code,
    which swallows it: a view once went on holding its last frame after Ctrl-C. A flag cannot be lost.
    """

    def __init__(self) -> None:
        self.asked = False
        self.before: dict[int, Any] = {}

    def __enter__(self) -> 'Interrupt':
        for sig in (signal.SIGINT, signal.SIGTERM):
            self.before[sig] = signal.signal(sig, self._on_signal)
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self.before.items():
            signal.signal(sig, handler)

    def _on_signal(self, signum: int, frame: object) -> None:
        self.asked = True

    def pause(self, seconds: float) -> bool:
        """Sleep up to seconds (in short naps, so that a Ctrl-C is acted on at once); True if one came."""
        end = time.monotonic() + max(seconds, 0.0)
        while not self.asked and time.monotonic() < end:
            time.sleep(min(0.05, end - time.monotonic()))
        return self.asked
