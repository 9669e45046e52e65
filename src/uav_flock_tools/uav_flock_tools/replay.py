"""`./uav-flock replay BAG --agent ID`: one MAP's recorded inputs fed to a fresh agent node.

The agent is a real `uav_agent_node` process in a domain of its own. Step by step, this node plays the
world and the neighbours from the bag, byte for byte: the scheduled failures of step k, the MAP's sensing
of step k, the step-k states of the neighbours it lists, then failures noticed during step k. It waits
for the agent's command and compares it with the recorded one: any change in the agent's behaviour
shows as a difference.
"""
from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Optional

import numpy as np

from uav_agent.core.params import FlockParams
from uav_flock_ros.processes import write_params

from . import bag, domains, spawn

if TYPE_CHECKING:
    from uav_flock_ros import convert

READY_TIMEOUT_S = 30.0  # the fresh agent must be on the graph within this


class ReplayError(Exception):
    """The replay could not run (not: the agent answered differently)."""


@dataclass
class Outcome:
    agent: int
    steps: int = 0                       # commands compared
    max_du: float = 0.0                  # largest |u_replayed - u_recorded| (m/s^2)
    mismatches: list[str] = field(default_factory=list)
    stuck_at: Optional[int] = None       # step the agent gave no command for
    tolerance: float = 1e-9
    note: str = ''
    changed: dict[str, object] = field(default_factory=dict)  # --set: an experiment, not a check
    du: list[tuple[float, float]] = field(default_factory=list)  # (t in s, |Δu|) of each step compared
    differing: list[int] = field(default_factory=list)  # steps whose command differs beyond the tolerance
    compared: list[int] = field(default_factory=list)  # the steps compared, in order
    mode_changes: int = 0  # steps whose mode differs from the recorded one
    goal_changes: int = 0

    @property
    def ok(self) -> bool:
        """A check passes when nothing differs; an experiment when it ran to the end of the recording."""
        if self.changed:
            return self.steps > 0 and self.stuck_at is None
        return self.steps > 0 and not self.mismatches and self.stuck_at is None

    def describe(self) -> str:
        return self.describe_experiment() if self.changed else self.describe_check()

    def describe_experiment(self) -> str:
        """How the commands with the parameters changed differ from the recorded ones, in a few lines."""
        setting = ', '.join(f'{k}={v}' for k, v in self.changed.items())
        du = np.array([d for _, d in self.du]) if self.du else np.zeros(1)
        lines = [f'MAP {self.agent} with {setting}: {self.steps} commands compared with the recording',
                 f'  |Δu|: max {du.max():.3g}, mean {du.mean():.3g} m/s^2; {len(self.differing)} of {self.steps} '
                 f'steps differ by more than {self.tolerance:g}']
        if self.differing:
            first = self.differing[0]
            t_first = next(t for (t, _), k in zip(self.du, self.compared) if k == first)
            lines.append(f'  first difference at step {first} (t = {t_first:.1f} s); '
                         f'{self.mode_changes} steps with another mode, {self.goal_changes} with another goal')
        else:
            lines.append('  no step differs: the change does not touch what this MAP did in this run')
        if self.stuck_at is not None:
            lines.append(f'  no command for step {self.stuck_at}: the agent waited for something the bag does not hold')
        if self.note:
            lines.append(f'  note: {self.note}')
        return '\n'.join(lines)

    def describe_check(self) -> str:
        head = (f'MAP {self.agent}: {self.steps} commands compared, max |Δu| = {self.max_du:.3g} m/s^2 '
                f'(tolerance {self.tolerance:g}), {len(self.mismatches)} mismatching')
        lines = [head] + [f'  {m}' for m in self.mismatches[:10]]
        if len(self.mismatches) > 10:
            lines.append(f'  ... {len(self.mismatches) - 10} more')
        if self.stuck_at is not None:
            lines.append(f'  no command for step {self.stuck_at}: the agent waited for something the bag '
                         'does not hold')
        if self.note:
            lines.append(f'  note: {self.note}')
        lines.append('same behaviour as recorded' if self.ok else 'behaviour differs from the recording')
        return '\n'.join(lines)


def replay(path: Path, agent: int, tolerance: float = 1e-9, timeout: float = 20.0,
           overrides: Optional[dict[str, object]] = None) -> Outcome:
    """Replay MAP `agent`; overrides change agent parameters (e.g. to see what a different gain does)."""
    if bag.recorded_sync(path) != 'lockstep':
        raise ReplayError(f'{path} was recorded with --sync {bag.recorded_sync(path)}, where each MAP flies on whatever '
                          'states have come in: its commands cannot be reproduced. Replay needs a lockstep bag '
                          '(`up --record`, the default sync)')
    inputs = bag.replay_inputs(path, agent)
    outcome = Outcome(agent, tolerance=tolerance)
    if not inputs.params:
        outcome.note = 'the bag carries no agent parameters (uav_flock.params): the defaults were used'
    if overrides:
        outcome.changed = checked_overrides(overrides, inputs.params)
        inputs.params = {**inputs.params, **outcome.changed}
    with domains.claim_domain() as domain, tempfile.TemporaryDirectory(prefix='uav-flock-replay-') as tmp:
        env = domains.ros_env(domain)
        params = write_params(Path(tmp) / 'agent_params.yaml', inputs.params)
        log = open(Path(tmp) / 'agent.log', 'w')
        proc = spawn.start_agent([agent], params, env, log)
        saved = {k: os.environ.get(k) for k in env}
        os.environ.update(env)

        def agent_exit() -> Optional[str]:
            """Why the agent ended, if it did: a parameter it rejects ends it at once, not after a timeout."""
            if proc.poll() is None:
                return None
            log.flush()
            last = (Path(log.name).read_text(errors='replace').strip().splitlines() or [''])[-1]
            how = spawn.describe_exit(proc.returncode)
            return f'the agent node of MAP {agent} ended ({how})' + (f': {last}' if last else '')

        try:
            _drive(inputs, outcome, timeout, agent_exit)
        finally:
            spawn.stop([proc])
            log.close()
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
    return outcome


def checked_overrides(overrides: dict[str, object], recorded: dict[str, object]) -> dict[str, object]:
    """--set KEY=VALUE pairs as agent parameters (`flock.c1` as in a scenario names c1 too), each checked as
    the agent node would check it, with the bag's other parameters: ReplayError in one line, before any
    process starts."""
    from uav_agent.core.checks import did_you_mean
    from uav_agent.core.policies import check
    names = [f.name for f in fields(FlockParams)]
    # `--set c1=1` reads as an integer; ROS parameters are typed, and the agent declares c1 a double.
    floats = {f.name for f in fields(FlockParams) if isinstance(f.default, float)}
    changed: dict[str, object] = {}
    for key, value in overrides.items():
        name = key.removeprefix('flock.')
        if name not in names:
            raise ReplayError(f'--set: no agent parameter {key!r}{did_you_mean(name, names)} '
                              f'(keys: {", ".join(names)})')
        changed[name] = float(value) if name in floats and type(value) is int else value
    base = {k: v for k, v in recorded.items() if k in names}
    try:
        check(FlockParams(**{**base, **changed}), lambda name: f'--set {name}')
    except ValueError as exc:
        raise ReplayError(str(exc)) from None
    return changed


def _drive(inputs: bag.ReplayInputs, outcome: Outcome, timeout: float,
           agent_exit: Callable[[], Optional[str]]) -> None:
    """Play the world and the neighbours to the agent step by step, comparing each command as it comes."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from uav_flock_ros.executors import signals_deferred

    context = rclpy.Context()
    # rclpy's signal handlers would turn Ctrl-C into a shutdown of the context and a traceback; without them
    # it is a KeyboardInterrupt, and replay's clean-up stops the agent before the CLI says "interrupted".
    with signals_deferred():
        rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    try:
        with signals_deferred():
            player = Player(inputs, context)
        player.wait_ready(agent_exit)
        for k in sorted(inputs.sensing):
            if k not in inputs.commands:
                break  # the MAP answered nothing more in the recording (killed, or the run ended)
            t = player.play(k)
            got = player.answer(k, timeout, agent_exit)
            if got is None:
                outcome.stuck_at = k
                return
            _compare(outcome, got, inputs.commands[k], t)
        player.node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


class Player:
    """The replay's node: the world's and the neighbours' recorded messages out, the agent's commands in."""

    def __init__(self, inputs: bag.ReplayInputs, context: object) -> None:
        import rclpy
        from rclpy.node import Node
        from uav_flock_msgs.msg import AgentState, Clusters, Command, FailureEvent, Sensing

        from uav_flock_ros import convert
        from uav_flock_ros.qos import LATCHED_QOS, STATE_QOS, STEP_QOS

        self.inputs, i = inputs, inputs.agent
        self.node = Node('replay', context=context)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.answers: dict[int, convert.CommandData] = {}
        self.node.create_subscription(Command, f'/map_{i}/cmd',
                                      lambda m: self.answers.__setitem__(int(m.step), convert.CommandData.from_msg(m)),
                                      STEP_QOS)
        self.clusters = self.node.create_publisher(Clusters, '/clusters', LATCHED_QOS)
        self.sensing = self.node.create_publisher(Sensing, f'/map_{i}/sensing', STEP_QOS)
        self.failures = self.node.create_publisher(FailureEvent, '/events/failure', STEP_QOS)
        self.states = {j: self.node.create_publisher(AgentState, f'/map_{j}/state', STATE_QOS)
                       for j in inputs.states if j != i}
        self.told_version = min(inputs.clusters)
        self.clusters.publish(inputs.clusters[self.told_version])
        self.pending_failures = list(inputs.failures)

    def wait_ready(self, agent_exit: Callable[[], Optional[str]]) -> None:
        deadline = time.monotonic() + READY_TIMEOUT_S
        i = self.inputs.agent
        while self.sensing.get_subscription_count() == 0 or self.node.count_publishers(f'/map_{i}/cmd') == 0:
            _still_starting(i, deadline, agent_exit)
            self.executor.spin_once(timeout_sec=0.05)

    def play(self, k: int) -> float:
        """Step k as world_sim sent it: scheduled failures, the survey, the sensing, the neighbours' states,
        then failures noticed during the step. Returns the step's simulated time."""
        from rclpy.serialization import deserialize_message
        from uav_flock_msgs.msg import Sensing
        inputs, pending = self.inputs, self.pending_failures
        while pending and (pending[0][0].step < k or (pending[0][0].step == k and pending[0][0].cause == 'scheduled')):
            self.failures.publish(pending.pop(0)[1])
        raw, sensed = inputs.sensing[k]
        version = sensed.clusters_version
        if version != self.told_version and version in inputs.clusters:
            self.clusters.publish(inputs.clusters[version])  # the survey's new picture, as world_sim sent it
            self.told_version = version
        self.sensing.publish(raw)
        for j in sensed.neighbour_ids.tolist():
            if k in inputs.states.get(j, {}):
                self.states[j].publish(inputs.states[j][k])
        while pending and pending[0][0].step == k:
            self.failures.publish(pending.pop(0)[1])
        stamp = deserialize_message(raw, Sensing).header.stamp
        return stamp.sec + stamp.nanosec * 1e-9

    def answer(self, k: int, timeout: float, agent_exit: Callable[[], Optional[str]]) -> Optional['convert.CommandData']:
        """The agent's command of step k, or None if none came within timeout."""
        until = time.monotonic() + timeout
        while k not in self.answers and time.monotonic() < until:
            self.executor.spin_once(timeout_sec=0.01)
            if k not in self.answers and (why := agent_exit()) is not None:
                raise ReplayError(f'at step {k}, {why}')
        return self.answers.pop(k, None)


def _still_starting(agent: int, deadline: float, agent_exit: Callable[[], Optional[str]]) -> None:
    """ReplayError if the fresh agent ended, or has not appeared by the deadline."""
    if (why := agent_exit()) is not None:
        raise ReplayError(why)
    if time.monotonic() > deadline:
        raise ReplayError(f'the agent node of MAP {agent} did not appear within {READY_TIMEOUT_S:g} s')


def _compare(outcome: Outcome, got: 'convert.CommandData', want: 'convert.CommandData', t: float) -> None:
    """One step's command against the recorded one."""
    du = float(np.max(np.abs(got.u - want.u)))
    outcome.max_du = max(outcome.max_du, du)
    outcome.steps += 1
    outcome.du.append((t, du))
    outcome.compared.append(got.step)
    outcome.mode_changes += got.mode != want.mode
    outcome.goal_changes += got.goal != want.goal
    if du > outcome.tolerance or got.mode != want.mode or got.goal != want.goal:
        outcome.differing.append(got.step)
        outcome.mismatches.append(f'step {got.step}: |Δu| = {du:.3g}, mode {got.mode} (recorded {want.mode}), '
                                  f'goal {got.goal} (recorded {want.goal})')
