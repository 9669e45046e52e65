"""The live view: a ROS node of its own, like foxglove_bridge, that serves a running formation to Foxglove.

It subscribes to what the world and the MAPs publish anyway (each MAP's sensing and state, `/metrics`,
failures), so it costs world_sim nothing, and serves the scene of `scene.py` through the Foxglove SDK's
WebSocket server behind gate.py (protocol `foxglove.sdk.v1`, or its former name `foxglove.websocket.v1` that
older Lichtblick releases offer), a step at a time
once the step is whole (scene.LiveSteps).
"""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Callable, Optional

import rclpy
from rclpy.node import Node

from uav_flock_msgs.msg import AgentState, FailureEvent, Metrics, Sensing
from uav_flock_ros import convert
from uav_flock_ros.executors import started
from uav_flock_ros.qos import STATE_QOS, STEP_QOS

from . import scene

DEFAULT_PORT = 8765


VIEW_START_S = 60.0  # the viewer imports rclpy and the SDK and starts its server well within this


def announce(viewer: subprocess.Popen, port: int, log: Path, stopping: Callable[[], bool]) -> None:
    """Say on the terminal, once, whether the live view serves: its URL and how to connect, or why not.

    The port was found free before the run, but another program may take it before the viewer binds it;
    the run then goes on without a view, and the user hears so here rather than only in viewer.log. A run
    that ends before the viewer serves (a short lockstep run) says nothing of it.
    """
    deadline = time.monotonic() + VIEW_START_S
    while time.monotonic() < deadline and not stopping():
        said = log.read_text(errors='replace') if log.exists() else ''
        if 'serving on' in said:
            print(f'uav-flock up: live view on ws://localhost:{port}: in Foxglove (or Lichtblick), Open connection, '
                  f'Foxglove WebSocket, that URL; docs/foxglove_layout.json lays out the 3-D scene and the plots',
                  flush=True)
            return
        if viewer.poll() is not None:
            why = next((line for line in reversed(said.splitlines()) if line.strip()), f'exit code {viewer.returncode}')
            print(f'uav-flock up: the live view is not served ({why.strip()}); the run goes on without it '
                  f'(logs/viewer.log)', flush=True)
            return
        time.sleep(0.2)
    if not stopping():
        print(f'uav-flock up: the live view did not start serving within {VIEW_START_S:.0f} s; the run goes on '
              f'(logs/viewer.log)', flush=True)


class ViewerError(Exception):
    """A viewer that cannot serve (its port is taken)."""


class Viewer(Node):
    def __init__(self) -> None:
        super().__init__('uav_flock_viewer')
        for name, default in (('maps', 0), ('r', 24.0), ('port', DEFAULT_PORT), ('host', '127.0.0.1')):
            self.declare_parameter(name, default)
        maps = int(self.get_parameter('maps').value)
        self.r = float(self.get_parameter('r').value)
        port, host = int(self.get_parameter('port').value), str(self.get_parameter('host').value)
        from . import gate
        try:
            self.server = gate.start_server(lambda line: self.get_logger().warning(line), host=host, port=port,
                                            name='uav-flock')
        except RuntimeError as exc:
            raise ViewerError(f'cannot serve on {host}:{port}: {exc}') from None
        self.channels = scene.Channels()
        self.steps = scene.LiveSteps()
        self.modes: dict[int, int] = {}
        self.subs = [self.create_subscription(AgentState, f'/map_{i}/state', self.on_state, STATE_QOS)
                     for i in range(maps)]
        self.subs += [self.create_subscription(Sensing, f'/map_{i}/sensing', self.on_sensing, STEP_QOS)
                      for i in range(maps)]
        self.subs += [self.create_subscription(Metrics, '/metrics', self.on_metrics, STEP_QOS),
                      self.create_subscription(FailureEvent, '/events/failure', self.on_failure, STEP_QOS)]

    def on_state(self, msg: AgentState) -> None:
        self.modes[int(msg.id)] = int(msg.mode)

    def on_sensing(self, msg: Sensing) -> None:
        self.draw(self.steps.sensed(int(msg.step), int(msg.id), convert.xyz(msg.position)))

    def on_failure(self, msg: FailureEvent) -> None:
        f = convert.FailureData.from_msg(msg)
        self.steps.dropped(f.step, f.ids, f.cause)

    def on_metrics(self, msg: Metrics) -> None:
        self.draw(self.steps.metrics(convert.MetricsData.from_msg(msg).row()))

    def draw(self, frames: list[scene.Frame]) -> None:
        """Each step's scene where the world put the MAPs, with the world's figures of that step."""
        for f in frames:
            self.channels.frame(f.t, scene.formation(f.t, f.ids, f.q, [self.modes.get(i, 0) for i in f.ids], self.r,
                                                     lost=f.gone),
                                scene.metrics(f.row), [scene.event(f.t, f'MAP {i} lost ({c})') for i, c in f.failures])

    def close(self) -> None:
        self.server.stop()


def main(argv: Optional[list[str]] = None) -> int:
    node, executor, stop = started('uav_flock_viewer', Viewer, (ViewerError,), argv)
    print(f'uav_flock_viewer: serving on ws://{node.get_parameter("host").value}:{node.server.port}', flush=True)
    try:
        stop.spin(executor)
    finally:
        node.close()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
