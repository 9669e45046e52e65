"""The physical world as an rclpy node: MSDs, dynamics, association and metrics, stepped with the MAPs.

Step k: drop failed MAPs, sense at q(k), publish /clock, /association and every live MAP's
/map_<id>/sensing; then record and integrate with the very `World` the batch simulator uses. The sync
mode says when a step ends:
- lockstep: once each live MAP's /map_<id>/cmd of step k is in (a MAP whose process is gone is dropped);
- realtime: on a wall-clock timer, every dt / rate, with the latest command each MAP has sent (held from
  an earlier step if none came for this one, for at most `command_ttl` steps; u = 0 before the first and
  after that), as an autopilot holds its last setpoint for a while and then stops acting on it.
"""
from __future__ import annotations

import collections
import sys
import time
from dataclasses import fields
from pathlib import Path
from typing import Callable, Optional

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.signals import SignalHandlerOptions
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Header, Int64, String
from visualization_msgs.msg import MarkerArray
from uav_flock_msgs.msg import Association, Clusters, Command, FailureEvent, Metrics, Sensing, Users

from uav_agent.core.checks import check_fields
from uav_agent.core.clusters import NO_GOAL
from uav_flock_ros import convert
from uav_flock_ros.executors import StopSignals, checked_ros_args, spun_node
from uav_flock_ros.processes import leave_after
from uav_flock_ros.qos import LATCHED_QOS, LATEST_QOS, STEP_QOS, is_realtime

from .core.model import Sensed, World
from .markers import world_markers
from .watch import LIVENESS_PERIOD_S, Watch
from .core import records
from .core.scenario import Scenario, ScenarioError, WorldNodeParams
from .shipped import DEFAULT, load_scenario

START_REPORT_S = 5.0
FINISHED_ACK_S = 2.0  # at most this long for every agent to acknowledge /events/finished before exit
# realtime: a pace below this fraction of the one asked for, over the last SLOW_WINDOW_S of simulated time (the
# start-up's first steps left out: their discovery is no measure of the run's pace), is reported once.
SLOW_AFTER_S = 2.0
SLOW_WINDOW_S = 3.0
SLOW_FRACTION = 0.95


def sim_time(t: float) -> Time:
    sec = int(np.floor(t))
    return Time(sec=sec, nanosec=int(round((t - sec) * 1e9)) % 1_000_000_000)


# Parameters that override the scenario, each with the default that means "the scenario's value".
SCENARIO_OVERRIDES = {'maps': 0, 'seed': -1, 'duration': 0.0, 'fail_at': -1.0, 'fail_fraction': -1.0, 'vehicle': ''}


class WorldNode(Watch, Node):
    def __init__(self, stopping: Callable[[], bool] = lambda: False) -> None:
        super().__init__('world_sim')
        # Told to stop (Ctrl-C on `up`, which stops the agents too): their deaths are not failures, and a
        # lockstep run must not go on to its end without them.
        self.stopping = stopping
        params, scenario = self.declared()
        self.scenario = scenario
        self.realtime = is_realtime(str(params.sync))
        self.rate = float(params.rate)  # realtime: simulated seconds per wall second
        self.command_ttl = int(params.command_ttl)  # realtime: steps a command is held at most
        self.world = World(scenario)
        self.out = Path(params.out) if params.out else None
        self.pid_table = Path(params.pid_table) if params.pid_table else None
        self.start_timeout = float(params.start_timeout)
        # With a recorder, the run waits for it at start and never gets more than
        # RECORDER_MAX_LAG_STEPS ahead of what it has written, so no sample leaves a writer unrecorded.
        self.record = bool(params.record)
        self.recorded = -2  # last /metrics step the recorder wrote; -1 once it is ready, -2 before
        self.recorder_moved = time.monotonic()
        self.held = False
        self.step_started = time.monotonic()
        self.resent = 0
        self.step_resends = 0  # repeats of the current step's sensing
        if self.record:
            self.create_subscription(Int64, '/recorder/progress', self.on_recorder, LATCHED_QOS)
        self.make_endpoints(params)

        self.sensed: Optional[Sensed] = None
        self.commands: dict[int, convert.CommandData] = {}  # lockstep: this step's; realtime: each MAP's latest
        self.fresh = self.applied = 0  # realtime: commands applied in the step they were computed for, of all
        self.last_mode: dict[int, int] = {}
        self.rejected = 0
        self.late = 0  # lockstep: commands of steps already past, ignored
        self.started = False
        self.finished = False
        self.advancing = False  # lockstep: inside maybe_advance's loop
        self.slow_said = False  # realtime: told the user once that the pace asked for is not kept
        self.paces: collections.deque[tuple[int, float]] = collections.deque()  # (step, wall time) of progress lines
        self.wall_start = time.monotonic()
        self.last_report = time.monotonic()  # of the start-up: a line every START_REPORT_S while we wait
        self.create_timer(LIVENESS_PERIOD_S, self.tick)

    def declared(self) -> tuple[WorldNodeParams, Scenario]:
        """The node's parameters, checked, and the scenario they name with the overrides they set."""
        own = WorldNodeParams()
        for name, default in (*((f.name, getattr(own, f.name)) for f in fields(WorldNodeParams)),
                              *SCENARIO_OVERRIDES.items()):
            self.declare_parameter(name, default)
        get = lambda n: self.get_parameter(n).value  # noqa: E731
        params = WorldNodeParams(**{f.name: get(f.name) for f in fields(WorldNodeParams)})
        check_fields(params, lambda name: f'parameter {name}')
        scenario = load_scenario(params.scenario or DEFAULT)
        # A parameter left at its default keeps the scenario's value; any other value is checked as the file's.
        return params, scenario.with_overrides(**{name: None if get(name) == unset else get(name)
                                                  for name, unset in SCENARIO_OVERRIDES.items()})

    def make_endpoints(self, params: WorldNodeParams) -> None:
        """The world's publishers (the fixed topics published once) and a reader of each MAP's commands."""
        n = self.scenario.maps
        self.clock_pub = self.create_publisher(Clock, '/clock', QoSProfile(depth=10))
        # The run's normal end (data: steps simulated): agents started by hand end with it, not with an error.
        self.finished_pub = self.create_publisher(Int64, '/events/finished', LATCHED_QOS)
        self.assoc_pub = self.create_publisher(Association, '/association', STEP_QOS)
        self.metrics_pub = self.create_publisher(Metrics, '/metrics', STEP_QOS)
        self.failure_pub = self.create_publisher(FailureEvent, '/events/failure', STEP_QOS)
        self.marker_period = int(params.marker_period)  # steps between /markers frames; 0: none
        self.markers_pub = self.create_publisher(MarkerArray, '/markers', STEP_QOS)
        self.users_pub = self.create_publisher(Users, '/users', LATCHED_QOS)
        self.clusters_pub = self.create_publisher(Clusters, '/clusters', LATCHED_QOS)
        self.sensing_pubs = [self.create_publisher(Sensing, f'/map_{i}/sensing', STEP_QOS) for i in range(n)]
        for i in range(n):
            self.create_subscription(Command, f'/map_{i}/cmd', lambda m, i=i: self.on_command(i, m),
                                     LATEST_QOS if self.realtime else STEP_QOS)
        if params.run_info:  # what agents joining from another host need: MAP count, ids, their parameters
            self.run_info_pub = self.create_publisher(String, '/run_info', LATCHED_QOS)
            self.run_info_pub.publish(String(data=Path(params.run_info).read_text()))
        self.publish_fixed()

    # ------------------------------------------------------------------ fixed topics
    def header(self) -> Header:
        return Header(stamp=sim_time(self.world.k * self.scenario.dt), frame_id='world')

    def publish_fixed(self) -> None:
        """/users and /clusters as they are before the first step."""
        self.publish_users()
        self.publish_clusters()

    def publish_users(self) -> None:
        u = self.world.users
        self.users_pub.publish(convert.UsersData(self.world.k, u.xyz, u.cluster).to_msg(self.header()))

    def publish_clusters(self) -> None:
        w = self.world
        c = w.clusters
        self.clusters_pub.publish(convert.ClustersData(w.clusters_version, c.xy, w.users.cluster_sizes, c.radii, c.active,
                                                       c.velocities[:, :2]).to_msg(self.header()))

    # ------------------------------------------------------------------ lockstep
    def tick(self) -> None:
        if not self.started:
            self.try_start()
        elif self.held and self.recorder_gone():
            self.held = False
            self.begin_step()
        elif not self.finished and not self.stopping():
            self.check_liveness()

    def try_start(self) -> None:
        """Begin once every MAP listens to its sensing topic and publishes commands."""
        ready = sum(1 for i in range(self.scenario.maps)
                    if self.sensing_pubs[i].get_subscription_count() > 0
                    and self.count_publishers(f'/map_{i}/cmd') > 0)
        if ready == self.scenario.maps and self.record and self.recorded < -1:
            if time.monotonic() - self.wall_start > self.start_timeout:
                self.get_logger().error(f'the recorder was not ready within {self.start_timeout:g} s')
                self.finish(ok=False)
            return
        if ready == self.scenario.maps:
            self.started = True
            self.get_logger().info(f'{ready} MAPs ready after {time.monotonic() - self.wall_start:.1f} s: starting')
            self.wall_start = time.monotonic()
            if self.realtime:
                self.create_timer(self.scenario.dt / self.rate, self.end_step_realtime)
            self.begin_step()
        elif time.monotonic() - self.wall_start > self.start_timeout:
            self.get_logger().error(f'only {ready} of {self.scenario.maps} MAPs appeared within {self.start_timeout:g} s '
                                    '(up --start-timeout SECONDS waits longer)')
            self.finish(ok=False)
        elif time.monotonic() - self.last_report >= START_REPORT_S:
            self.last_report = time.monotonic()
            print(f'waiting for the MAPs: {ready} of {self.scenario.maps} ready after '
                  f'{time.monotonic() - self.wall_start:.0f} s', flush=True)

    def begin_step(self) -> None:
        w = self.world
        failing = w.scheduled_failures()
        if len(failing):
            self.drop(failing, 'scheduled')
            self.kill_processes(failing)
        clusters_changed, users_moved = w.place_users()
        if clusters_changed:
            self.publish_clusters()  # before the sensing that names its version
        if users_moved and w.k > 0:
            self.publish_users()
        self.sensed = s = w.sense()
        if not self.realtime:
            self.commands = {}
        self.step_started = time.monotonic()
        self.step_resends = 0
        hdr = self.header()
        self.clock_pub.publish(Clock(clock=hdr.stamp))
        self.assoc_pub.publish(convert.AssociationData(s.k, s.ids, s.n_users, s.cluster_coverage,
                                                       s.coverage_ratio).to_msg(hdr))
        self.publish_sensing(hdr)
        if not self.realtime:
            self.maybe_advance()  # no live MAP left to wait for: no command will ever come

    def publish_sensing(self, hdr: Header, only: Optional[set[int]] = None) -> None:
        """The step's sensing to every flying MAP, or to the MAPs in `only`."""
        s, w = self.sensed, self.world
        for row, i in enumerate(s.ids.tolist()):
            if only is not None and i not in only:
                continue
            nbr, seen = s.neighbours(row), s.heard_traffic(row)
            goal = int(w.goal[i])
            self.sensing_pubs[i].publish(convert.SensingData(
                i, s.k, s.q[row], s.p[row], int(s.n_users[row]),
                float(s.cluster_coverage[goal]) if goal != NO_GOAL else 0.0, s.ids[nbr],
                np.linalg.norm(s.q[nbr] - s.q[row], axis=1), w.clusters_version, s.ids[seen], s.q[seen],
                s.p[seen]).to_msg(hdr))

    def on_command(self, sender: int, raw: Command) -> None:
        msg = convert.CommandData.from_msg(raw)
        s = self.sensed
        if s is None or self.finished:
            return
        known = self.commands.get(sender)
        if not self.realtime and msg.step < s.k and msg.id == sender:
            self.late += 1  # a copy of a past step's command (a repeat, or handed over at matching)
            return
        if self.realtime:  # any step up to the current one, never older than what we hold
            bad_step = msg.step > s.k or (known is not None and msg.step < known.step)
        else:
            bad_step = msg.step != s.k
        flying = self.world.alive[sender] if self.realtime else sender in s.ids
        if msg.id != sender or bad_step or not np.all(np.isfinite(msg.u)) or not flying:
            self.rejected += 1
            if self.rejected == 1:
                self.get_logger().warning(f'rejected a command on /map_{sender}/cmd (id {msg.id}, step {msg.step}); '
                                          'further ones only counted')
            return
        self.commands[sender] = msg
        if not self.realtime:
            self.maybe_advance()

    def waiting_for_commands(self) -> bool:
        return any(self.world.alive[i] and i not in self.commands for i in self.sensed.ids.tolist())

    def maybe_advance(self) -> None:
        """lockstep: end the step once every live MAP's command of it is in.

        A step with no live MAP ends at once, and so does the next. The loop, not recursion through
        begin_step, carries a run whose MAPs have all failed through its remaining steps, as `sim` does.
        """
        if self.advancing:
            return
        self.advancing = True
        try:
            while not (self.finished or self.held or self.sensed is None or self.stopping()
                       or self.waiting_for_commands()):
                self.end_step([self.commands.get(i) for i in self.sensed.ids.tolist()])
        finally:
            self.advancing = False

    def end_step_realtime(self) -> None:
        """realtime: the step's time is up; each live MAP flies on the latest command it sent."""
        if self.sensed is None or self.finished or self.held:
            return
        ids, k = self.sensed.ids.tolist(), self.sensed.k
        cmds = [c if self.world.alive[i] and (c := self.commands.get(i)) is not None and k - c.step < self.command_ttl
                else None for i in ids]
        self.applied += len(ids)
        self.fresh += sum(1 for c in cmds if c is not None and c.step == self.sensed.k)
        self.end_step(cmds)

    def end_step(self, cmds: list[Optional[convert.CommandData]]) -> None:
        """Record the step and integrate it; a MAP with no command (dead, or none yet) flies with u = 0."""
        s = self.sensed
        u = np.array([c.u if c else np.zeros(3) for c in cmds]).reshape(-1, 3)
        modes = np.array([c.mode if c else self.last_mode.get(i, 0) for c, i in zip(cmds, s.ids.tolist())],
                         dtype=np.intp)
        goals = np.array([c.goal if c else self.world.goal[i] for c, i in zip(cmds, s.ids.tolist())],
                         dtype=np.intp)
        self.last_mode.update(zip(s.ids.tolist(), modes.tolist()))
        last = self.world.k >= self.scenario.steps
        if self.marker_period > 0 and s.k % self.marker_period == 0:
            self.markers_pub.publish(world_markers(self.header(), s, modes, self.world.users))
        did = np.array([c.filter if c else 0 for c in cmds], dtype=np.uint8)
        row = self.world.advance(s, u, modes, goals, integrate=not last, flags=did)
        self.publish_metrics(row)
        if last:
            self.finish(ok=True)
        else:
            self.next_step()

    # ------------------------------------------------------------------ recorder
    def next_step(self) -> None:
        if self.recorder_behind() and not self.realtime:  # realtime keeps its pace: it never waits
            self.held = True
            return
        self.begin_step()

    def publish_metrics(self, row: np.ndarray) -> None:
        m = convert.MetricsData.of_row(row.tolist())
        k, t, rc, lam2, alive, m0, m1, m2 = m.step, m.t, m.coverage_ratio, m.fiedler, m.alive, m.mode0, m.mode1, m.mode2
        self.metrics_pub.publish(m.to_msg(Header(stamp=sim_time(t), frame_id='world')))
        if int(k) % int(round(1.0 / self.scenario.dt)) == 0:
            wall = time.monotonic() - self.wall_start
            fresh = ''
            if self.realtime and self.applied:
                fresh = f'  fresh commands {100 * self.fresh / self.applied:.0f} %'
                self.fresh = self.applied = 0
            pace = (k + 1) / max(wall, 1e-9)
            print(f't = {t:5.1f} s  R_c = {100 * rc:5.1f} %  λ2 = {lam2:.4f}  alive = {int(alive)}  '
                  f'modes = {int(m0)}/{int(m1)}/{int(m2)}  {pace:.1f} steps/s{fresh}', flush=True)
            asked = self.rate / self.scenario.dt  # realtime's steps per wall second
            if self.realtime and t >= SLOW_AFTER_S:
                self.paces.append((int(k), wall))
            if self.paces and int(k) - self.paces[0][0] >= SLOW_WINDOW_S / self.scenario.dt:
                k0, wall0 = self.paces.popleft()
                recent = (int(k) - k0) / max(wall - wall0, 1e-9)
                if not self.slow_said and recent < SLOW_FRACTION * asked:
                    self.slow_said = True
                    print(f'realtime x{self.rate:g} asks for {asked:g} steps/s and this machine kept {recent:.1f} '
                          f'over the last {SLOW_WINDOW_S:g} s ({recent / asked:.2f} of it): the run goes slower than '
                          'asked; fewer processes (a larger --agents-per-process K) or a lower --rate keep the pace',
                          flush=True)

    # ------------------------------------------------------------------ end
    def done(self) -> bool:
        """Finished, and the recorder (if any) has written the last step or stopped answering: only then may the
        agents hear of the end, since a MAP's writer that goes first can take its last command with it."""
        if not self.finished:
            return False
        if not self.ok or not self.record or self.recorded >= self.world.k:
            return True
        return self.recorder_gone()

    def finish(self, ok: bool) -> None:
        self.finished = True
        self.ok = ok
        if self.resent:
            steps = f'{self.resent} stalled steps had their' if self.resent > 1 else '1 stalled step had its'
            print(f'{steps} sensing sent again (delays of discovery or delivery; '
                  'lockstep results do not depend on them; logs/world.log says which)', flush=True)
        self.recorder_moved = time.monotonic()
        if self.out is None:
            return
        result = self.world.result()
        if len(result.metrics) > 0:  # a run that never started leaves no records
            self.out.mkdir(parents=True, exist_ok=True)
            records.write_metrics(self.out / 'metrics.csv', result.metrics)
            records.write_trajectory(self.out / 'trajectory.csv', result.trajectory)
            records.write_users(self.out / records.USERS_FILE, result.users, result.motion)
            records.write_failures(self.out / records.FAILURES_FILE, result.failed, result.fail_step, result.events)


def main(argv: Optional[list[str]] = None) -> int:
    if checked_ros_args('world_sim_node', sys.argv if argv is None else argv) is None:
        return 2
    rclpy.init(args=sys.argv if argv is None else argv, signal_handler_options=SignalHandlerOptions.NO)
    stop = StopSignals()  # SIGINT or SIGTERM: the records are written before exit
    node, executor = spun_node('world_sim', lambda: WorldNode(lambda: stop.received), (ScenarioError,))
    if node is None or executor is None:
        return 2
    try:
        while not stop.received and not node.done():
            executor.spin_once(timeout_sec=0.1)
        if not node.finished:
            node.finish(ok=False)  # keep what was simulated
        elif node.ok:  # only once the recorder holds the last step: the agents' writers go when they learn of it
            node.finished_pub.publish(Int64(data=int(node.world.k)))
            node.finished_pub.wait_for_all_acked(Duration(seconds=FINISHED_ACK_S))
        node.flush()
    finally:
        code = 0 if getattr(node, 'ok', False) else 1
        leave_after(code, 'world_sim')  # the records are written: nothing is lost past here
        node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == '__main__':
    sys.exit(main())
