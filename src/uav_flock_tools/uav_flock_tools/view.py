"""`view BAG`: a recorded run played into the live view's server at its recorded pace (no ROS needed).

Foxglove or Lichtblick connect to it exactly as to `up --view`, and see the same channels (scene.py).
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Callable, Optional

from world_sim.core import records

from . import bag, report, scene


def play(path: Path, port: int, rate: float = 1.0, loop: bool = False,
         said: Callable[[str], None] = print) -> int:
    """Serve the bag's frames on ws://localhost:port, t seconds of the run at t / rate seconds of the wall
    clock; returns how many frames went out. ValueError if the port cannot be served."""
    import foxglove
    run = bag.load(path)
    bag.summary(run)  # a bag without /metrics is refused here, with its reason
    traj = records.columns(run.trajectory)
    try:
        server = foxglove.start_server(name='uav-flock', host='127.0.0.1', port=port,
                                        capabilities=[foxglove.Capability.Time])  # the recording's clock
    except RuntimeError as exc:
        raise ValueError(f'--port {port}: cannot serve there ({exc})') from None
    said(f'view: serving {path} on ws://localhost:{server.port}: in Foxglove (or Lichtblick), Open connection, '
          'Foxglove WebSocket, that URL; docs/foxglove_layout.json lays out the 3-D scene and the plots; Ctrl-C ends')
    channels, sent = scene.Channels(), 0
    try:
        while True:
            began: Optional[float] = None
            for t, update, figures, logs in report.scene_frames(run, traj):
                began = time.monotonic() - t / rate if began is None else began
                time.sleep(max(began + t / rate - time.monotonic(), 0.0))
                server.broadcast_time(scene.nanoseconds(t))
                channels.frame(t, update, figures, logs)
                sent += 1
            if not loop:
                return sent
    finally:
        server.stop()
