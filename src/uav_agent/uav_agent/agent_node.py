"""One MAP as an rclpy node: hears only its radio neighbours, computes u_i and its mode with the core.

For step k the world sends /map_<id>/sensing (own q, p, N_u, r_g, neighbour ids) and the MAP publishes
its /map_<id>/state for step k. Then, by sync mode:
- lockstep: it waits for the step-k states of exactly the listed neighbours, runs `agent_step` and
  publishes /map_<id>/cmd for step k (deterministic: equal to the batch simulator);
- realtime: it runs `agent_step` at once on the latest state it holds of each listed neighbour, as an
  aircraft would with whatever its radio last brought in.
"""
from __future__ import annotations

import time
from dataclasses import fields
from pathlib import Path
from typing import Optional

import numpy as np
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.subscription import Subscription
from std_msgs.msg import Header, Int64
from uav_flock_msgs.msg import AgentState, Clusters, Command, FailureEvent, Sensing
from uav_flock_ros import convert
from uav_flock_ros.qos import LATCHED_QOS, LATEST_QOS, LATEST_STATE_READ_QOS, STATE_QOS, STEP_QOS, is_realtime

from .core import links
from .core.agent import Said, agent_step
from .core.ear import Ear, Heard, Passed, Sent, hear
from .core.clusters import NO_GOAL, ClusterMap, ids_of, mask_of
from .core.state import Memory, Told
from .core.checks import check_fields
from .core.params import AgentNodeParams, FlockParams
from .core.policies import check as check_params
from .core.policies import hearsay
from .recovery import SWEEP_PERIOD_S, WATCH_PERIOD_S, Recovery

# realtime: a neighbour's state may run ahead of our sensing by a few steps (it was sensed first), no more
REALTIME_AHEAD_STEPS = 10
# What a MAP holds of its run (AgentNode.__init__ and channel), carried to a participant made anew mid-run.
CARRIED = ('memory', 'held', 'clusters', 'clusters_version', 'pending', 'pending_header', 'step', 'own_q', 'latest',
           'dead', 'rejected', 'repeats', 'last_state', 'last_cmd', 'failed', 'stopped', 'run_finished', 'world_seen',
           'ear', 'own_at', 'discarded')


class AgentNode(Recovery, Node):
    """MAP <id> in namespace /map_<id>."""

    def __init__(self, map_id: int, context: Optional[Context] = None) -> None:
        # No parameter or type-description services: they are 7 readers and 7 writers more per MAP, and Fast
        # DDS pairs every new neighbour reader with every writer it knows. 200 MAPs in one process made 4
        # steps in 5 minutes with them and 50 steps in 4 minutes without (docs/benchmarks.md). Parameters
        # still come from the YAML file; `agent_params.yaml` in the run folder holds them.
        super().__init__('agent', namespace=f'map_{map_id}', context=context, start_parameter_services=False,
                         parameter_overrides=[Parameter('start_type_description_service', value=False)])
        self.map_id = map_id
        defaults = FlockParams()
        for f in fields(FlockParams):
            self.declare_parameter(f.name, getattr(defaults, f.name))
        node_defaults = AgentNodeParams()
        for f in fields(AgentNodeParams):
            self.declare_parameter(f.name, getattr(node_defaults, f.name))
        self.params = FlockParams(**{f.name: self.get_parameter(f.name).value for f in fields(FlockParams)})
        check_params(self.params, lambda name: f'parameter {name}')
        node = AgentNodeParams(**{f.name: self.get_parameter(f.name).value for f in fields(AgentNodeParams)})
        check_fields(node, lambda name: f'parameter {name}')
        self.hysteresis = float(node.hysteresis)
        self.realtime = is_realtime(str(node.sync))
        self.world_start_timeout = float(node.world_start_timeout)
        self.renew_unseen = float(node.renew_unseen)
        self.crash_dir = str(node.crash_dir)
        self.channel(str(node.links_log))
        self.world_seen = False

        self.memory = Memory()
        self.held = 0  # the safety filter's liveness count (agent.Step.held)
        self.clusters: Optional[ClusterMap] = None
        self.clusters_version = 0  # of the clusters held; a step waits for the version its sensing names
        self.pending: Optional[convert.SensingData] = None
        self.pending_header: Optional[Header] = None  # the pending sensing's, which its state and command carry
        self.step = -1  # the last step the world sensed for us
        self.own_q = np.zeros(3)
        self.latest: dict[int, convert.AgentStateData] = {}
        self.neighbour_subs: dict[int, Subscription] = {}
        self.dead: set[int] = set()
        self.rejected: dict[str, int] = {}
        self.repeats: dict[str, int] = {}  # late copies of earlier steps: normal on a busy DDS, only counted
        self.stopped = False
        self.run_finished = False  # stopped because world_sim ended the run normally
        self.last_state: Optional[AgentState] = None
        self.last_cmd: Optional[tuple[int, Command]] = None  # (step, message), said again on a repeat
        self.failed = False  # this MAP failed by the schedule (its process lives on for other MAPs)
        self.resubscribed = (-1, 0)  # (step, times its silent neighbours' readers were made anew)
        self.silent_writers = False  # a neighbour the pending step waits for has a matched writer, unheard

        self.state_pub = self.create_publisher(AgentState, 'state', STATE_QOS)
        self.cmd_pub = self.create_publisher(Command, 'cmd', STEP_QOS)
        self.sensing_sub = self.create_subscription(Sensing, 'sensing', self.on_sensing,
                                                    LATEST_QOS if self.realtime else STEP_QOS)
        self.create_subscription(Clusters, '/clusters', self.on_clusters, LATCHED_QOS)
        self.create_subscription(FailureEvent, '/events/failure', self.on_failure, STEP_QOS)
        self.create_subscription(Int64, '/events/finished', self.on_finished, LATCHED_QOS)
        self.sensed_at = time.monotonic()  # when the pending step's sensing came in
        self.next_report = 2.0
        self.create_timer(WATCH_PERIOD_S, self.watch_world)
        if not self.realtime:
            self.create_timer(SWEEP_PERIOD_S, self.sweep)

    def channel(self, log: str) -> None:
        """The radio to the neighbours (links.py): the run's channel and seed, what this MAP holds of its
        neighbours' states under it, and in realtime where it writes each state's fate (links_log)."""
        for f in fields(links.Links):
            self.declare_parameter(f'links.{f.name}', getattr(links.Links(), f.name))
        self.declare_parameter('seed', 0)
        self.declare_parameter('dt', 0.1)
        self.links = links.check(links.Links(**{f.name: self.get_parameter(f'links.{f.name}').value
                                                for f in fields(links.Links)}), lambda name: f'parameter links.{name}')
        self.seed = int(self.get_parameter('seed').value)  # the run's: every channel decision draws from it
        self.dt = float(self.get_parameter('dt').value)  # the run's step (s): how far a stale state is flown on
        self.ear = Ear(self.links, self.seed, self.map_id, hearsay(self.params))  # what it holds of its neighbours
        self.own_at: dict[int, np.ndarray] = {}  # realtime: this MAP's position at its recent steps
        self.discarded = 0  # realtime: neighbour states the channel lost
        self.links_log = None
        if log and self.realtime and not self.links.perfect:
            Path(log).mkdir(parents=True, exist_ok=True)
            self.links_log = open(Path(log) / f'map_{self.map_id}.csv', 'w', buffering=1 << 16)
            self.links_log.write('step,sender,x_rx,y_rx,z_rx,x_tx,y_tx,z_tx,heard\n')

    # ------------------------------------------------------------------ inputs
    def reject(self, source: str, why: str) -> None:
        """Count a bad message; log the first one per source only."""
        self.rejected[source] = self.rejected.get(source, 0) + 1
        if self.rejected[source] == 1:
            self.get_logger().warning(f'rejected a message from {source}: {why} (further ones only counted)')

    def repeat(self, source: str) -> None:
        """Count a message of a step already past: the world and neighbours repeat a stalled step's
        messages, and a late copy changes nothing, so it is no warning; the counts go in the log at the end."""
        self.repeats[source] = self.repeats.get(source, 0) + 1

    def summary(self) -> None:
        """At the end: what was ignored, in one line, if anything."""
        if self.links_log is not None:
            self.links_log.close()
        if self.discarded:
            self.get_logger().info(f'the channel lost {self.discarded} neighbour states')
        if self.repeats:
            told = ', '.join(f'{n} from {src}' for src, n in sorted(self.repeats.items()))
            self.get_logger().info(f'ignored {sum(self.repeats.values())} late copies of past steps ({told})')

    def on_clusters(self, msg: Clusters) -> None:
        c = convert.ClustersData.from_msg(msg)
        if not np.all(np.isfinite(c.xy)) or len(c.xy) == 0:
            self.reject('/clusters', 'no or non-finite centroids')
            return
        if (c.radii is None and len(msg.radii)) or (c.radii is not None and not np.all(np.isfinite(c.radii) & (c.radii >= 0))):
            self.reject('/clusters', f'{len(msg.radii)} radii for {len(c.xy)} centroids, or a negative or non-finite one')
            return
        if not np.all(np.isfinite(c.velocities)):
            self.reject('/clusters', 'non-finite velocities')
            return
        if self.clusters is not None and c.version <= self.clusters_version:
            return  # the picture held, or an older one arriving late
        # Roles carry their keys over from the survey before, as world_sim's batch twin does (ClusterMap).
        self.clusters = ClusterMap(c.xy, self.params.height, c.radii, c.active, c.velocities, previous=self.clusters)
        self.clusters_version = c.version
        self.try_step()

    def on_finished(self, msg: Int64) -> None:
        self.get_logger().info(f'world_sim finished the run after {msg.data} steps: stopping MAP {self.map_id}')
        self.run_finished = self.stopped = True

    def crash(self) -> None:
        """Fall silent at once, as a crash would. Events the executor queued before the node goes still come in:
        with failed set and no step pending, each is a no-op (none uses the node's handles)."""
        self.failed = True
        self.pending = None

    def on_failure(self, msg: FailureEvent) -> None:
        event = convert.FailureData.from_msg(msg)
        self.dead.update(event.ids)
        if self.map_id in self.dead and not self.failed:
            # Failed by the schedule while sharing a process with live MAPs: fall silent, as if killed.
            self.failed = True
            self.pending = None
            self.get_logger().warning(f'MAP {self.map_id} failed (event at step {event.step}): silent from now on')
            return
        self.try_step()

    def on_sensing(self, msg: Sensing) -> None:
        if self.failed:
            return
        s = convert.SensingData.from_msg(msg)
        if s.id != self.map_id or not convert.finite(msg.position, msg.velocity, msg.goal_coverage):
            self.reject('sensing', f'id {s.id} or non-finite values')
            return
        if s.step == self.step and self.step >= 0 and not self.realtime:
            self.answer_again()  # the world repeats a stalled step: say again what we said
            return
        if s.step < self.step or (self.realtime and s.step == self.step):
            self.repeat('sensing')
            return
        self.sensed_at = time.monotonic()
        self.next_report = 2.0
        self.world_seen = True
        self.pending, self.pending_header = s, msg.header
        self.step = s.step
        self.own_q = s.q
        if self.realtime and not self.links.perfect:
            self.own_at[s.step] = s.q
            self.own_at.pop(s.step - REALTIME_AHEAD_STEPS - self.links.ttl, None)
        self.publish_state(s)
        self.follow(s.neighbour_ids.tolist())
        self.try_step()

    def on_state(self, sender: int, raw: AgentState) -> None:
        source = f'/map_{sender}/state'
        msg = convert.AgentStateData.from_msg(raw)
        if msg.id != sender:
            self.reject(source, f'sender id {msg.id} on the topic of MAP {sender}')
            return
        if not convert.finite(raw.position, raw.velocity, *(v for r in raw.passed_on for v in (r.position, r.velocity))):
            self.reject(source, 'non-finite position or velocity')
            return
        known = self.latest.get(sender)
        ahead = REALTIME_AHEAD_STEPS if self.realtime else 1  # in lockstep a neighbour is at most a step ahead
        if known is not None and msg.step < known.step:
            self.repeat('neighbour states')
            return
        if msg.step > self.step + ahead:  # no neighbour gets that far ahead: something is wrong
            self.reject(source, f'step {msg.step} ahead of this MAP (now at {self.step})')
            return
        if self.realtime and not self.links.perfect and not self.delivered(msg):
            return
        self.latest[sender] = msg
        if not self.realtime:
            self.try_step()

    def delivered(self, msg: convert.AgentStateData) -> bool:
        """Realtime under a channel: whether the state that just arrived is heard (ear.hear, from this MAP's
        position at the state's step if it has it, else its latest); a lost one is gone, a heard one is held
        until it may be used (ear.Ear)."""
        here = self.own_at.get(msg.step, self.own_q)
        ok = bool(hear([self.ear], msg.step, here[None, :], [[sent(msg)]], self.params.r)[0][0])
        if self.links_log is not None:
            self.links_log.write(f'{msg.step},{msg.id},{here[0]:.17g},{here[1]:.17g},{here[2]:.17g},'
                                 f'{msg.q[0]:.17g},{msg.q[1]:.17g},{msg.q[2]:.17g},{int(ok)}\n')
        if not ok:
            self.discarded += 1
        return ok

    # ------------------------------------------------------------------ neighbours
    def follow(self, listed: list[int]) -> None:
        """Subscribe to the listed neighbours; keep others only while within r + hysteresis."""
        keep = set(listed)
        for j in self.neighbour_subs:
            s = self.latest.get(j)
            if s is not None and j not in self.dead and \
                    np.linalg.norm(s.q - self.own_q) <= self.params.r + self.hysteresis:
                keep.add(j)
        for j in set(self.neighbour_subs) - keep:
            self.destroy_subscription(self.neighbour_subs.pop(j))
            self.latest.pop(j, None)
        for j in sorted(keep - set(self.neighbour_subs)):
            self.subscribe(j)

    def subscribe(self, j: int) -> None:
        old = self.neighbour_subs.pop(j, None)
        if old is not None:
            self.destroy_subscription(old)
        self.neighbour_subs[j] = self.create_subscription(
            AgentState, f'/map_{j}/state', lambda m, j=j: self.on_state(j, m),
            LATEST_STATE_READ_QOS if self.realtime else STATE_QOS)

    def carry(self, old: 'AgentNode') -> None:
        """Go on where `old`, the same MAP on the participant a renewal replaces mid-run, left off: what it decided,
        heard and said. Its neighbours are subscribed to anew and what it said of its last step is said again,
        so a neighbour waiting for it hears it, and a lockstep run ends as it would have (recovery.stuck_midway)."""
        for name in CARRIED:
            setattr(self, name, getattr(old, name))
        self.sensed_at = time.monotonic()  # a renewal's stall counts afresh, and so do its readers made anew
        self.resubscribed = (-1, 0)
        if self.failed:
            return  # failed by the schedule: silent, as before
        for j in sorted(old.neighbour_subs):
            self.subscribe(j)
        self.answer_again()

    # ------------------------------------------------------------------ step
    def answer_again(self) -> None:
        if self.last_state is not None:
            self.state_pub.publish(self.last_state)
        if self.last_cmd is not None and self.last_cmd[0] == self.step:
            self.cmd_pub.publish(self.last_cmd[1])

    def publish_state(self, s: convert.SensingData) -> None:
        mem = self.memory
        told = Told.of(mem)
        passed_on = tuple(convert.PassedData(j, at, h.q, h.p, int(h.n_users), h.said.told.mode, h.said.told.goal,
                                             h.said.told.bridge, tuple(ids_of(h.said.achieved)), h.said.told.block)
                          for j, at, h in self.ear.passed)
        msg = convert.AgentStateData(self.map_id, s.step, s.q, s.p, s.n_users, mem.mode, mem.goal, mem.bridge,
                                     tuple(ids_of(mem.achieved)), told.block, passed_on).to_msg(self.pending_header)
        self.state_pub.publish(msg)
        self.last_state = msg

    def try_step(self) -> None:
        """Compute the pending step's command once what the sync mode needs from the neighbours is here."""
        s = self.pending
        if s is None or self.clusters is None or self.clusters_version < s.clusters_version:
            return
        needed = [j for j in s.neighbour_ids.tolist() if j not in self.dead]
        if not self.realtime:  # the states of step s of the listed neighbours, in ascending id as the world lists them
            if self.unheard(s):
                return
            hear([self.ear], s.step, s.q[None, :], [[sent(self.latest[j]) for j in needed]], self.params.r)
        elif self.links.perfect:  # whatever came in, of any step, taken for this step's
            hear([self.ear], s.step, s.q[None, :], [[sent(self.latest[j]) for j in needed if j in self.latest]], self.params.r)
        # realtime under a channel: what it delivered is in the ear already (delivered)
        hood = self.ear.neighbourhood(s.step, self.dt, s.q, self.params.r)
        coverage = np.zeros(self.clusters.count)
        if self.memory.goal != NO_GOAL:
            coverage[self.memory.goal] = s.goal_coverage  # r_g of the goal the world knows we hold
        u, mem, did, self.held = agent_step(self.memory, self.map_id, s.q, s.p, s.n_users, coverage, hood,
                                            self.clusters, self.params, s.step, (s.traffic_q, s.traffic_p), self.held)
        if not np.all(np.isfinite(u)):
            self.reject('core', f'non-finite control input at step {s.step}; holding u = 0')
            u = np.zeros(3)
        self.memory = mem
        self.pending = None
        self.last_cmd = (s.step, convert.CommandData(self.map_id, s.step, u, mem.mode, mem.goal, did).to_msg(self.pending_header))
        self.cmd_pub.publish(self.last_cmd[1])

    def unheard(self, s: convert.SensingData) -> list[int]:
        """The live neighbours listed for step s whose state of that step has not come in."""
        return [j for j in s.neighbour_ids.tolist() if j not in self.dead and (j not in self.latest or self.latest[j].step != s.step)]


def said(m: convert.AgentStateData | convert.PassedData) -> Said:
    """What a neighbour's state message says, as the step reads it (core.agent.Neighbourhood.hearing)."""
    return Said(mask_of(m.achieved), Told(m.mode, m.goal, m.bridge, m.roles))


def sent(m: convert.AgentStateData) -> Sent:
    """A neighbour's state message as the MAP's ear takes it, with the states it passes on (AgentState.passed_on)."""
    return Sent(m.id, Heard(m.q, m.p, float(m.n_users), said(m)),
                [Passed(r.id, r.step, Heard(r.q, r.p, float(r.n_users), said(r))) for r in m.passed_on])
