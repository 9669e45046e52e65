"""`echo` and `topics` for installs without ros2cli: the YAML of `ros2 topic echo`, the list of `ros2 topic list -t`."""
from __future__ import annotations

import importlib
import json
import math
import os
import re
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional

import yaml

if TYPE_CHECKING:
    from uav_flock_ros.executors import StopSignals

DISCOVERY_S = 1.5  # least time given to discovery before listing
SETTLED_S = 1.0  # ... and the list must not have grown for this long
DISCOVERY_MAX_S = 20.0
QUIET_S = 5.0  # with no run named, a domain where no other participant has shown a topic by then holds no run
OWN_TOPICS = {'/rosout', '/parameter_events'}  # every node has them, ours included


class EchoError(Exception):
    """A topic that cannot be echoed here: a bad name, or a type this install lacks."""


def use_domain(run: Optional[str], domain_id: Optional[int]) -> None:
    """Point this process at a run's domain (from its run.json) or an explicit one."""
    if run is not None:
        from .kill import run_has_ended
        info = Path(run) / 'run.json'
        if not info.exists():
            raise FileNotFoundError(f'--run: {run} has no run.json (is it a run folder of ./uav-flock up?)')
        if run_has_ended(Path(run)):  # its topics are gone: say so now rather than after a long wait
            raise EchoError(f'--run: the run in {run} has ended (its world_sim is gone)')
        meta = json.loads(info.read_text())
        domain_id = int(meta['domain_id'])
        if meta.get('secure'):  # a super client of the run over TLS, with this host's keys
            from .domains import adopt
            from .secure import environment
            adopt(environment(dict(os.environ), Path(meta['secure']['super_client'])))
        elif meta.get('discovery_server'):  # a super client sees every endpoint the server knows
            os.environ.update(ROS_DISCOVERY_SERVER=meta['discovery_server'], ROS_SUPER_CLIENT='TRUE')
        elif meta.get('discovery_range'):
            os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = meta['discovery_range']
    if domain_id is not None:
        os.environ['ROS_DOMAIN_ID'] = str(domain_id)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')


def to_plain(value: Any) -> Any:
    """A message as nested dicts and lists, field order kept (what ros2cli's message_to_ordereddict gives)."""
    if hasattr(value, 'get_fields_and_field_types'):
        return {name: to_plain(getattr(value, name)) for name in value.get_fields_and_field_types()}
    if hasattr(value, 'tolist'):
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        return [to_plain(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return value


def to_yaml(msg: Any) -> str:
    return yaml.safe_dump(to_plain(msg), default_flow_style=False, sort_keys=False, width=10**9) + '---'


def message_type(name: str) -> type:
    """'uav_flock_msgs/msg/AgentState' -> the class."""
    pkg, kind, cls = name.split('/')
    try:
        return getattr(importlib.import_module(f'{pkg}.{kind}'), cls)
    except (ImportError, AttributeError):
        raise EchoError(f'its type {name} is not installed in this environment') from None


def expected_topics(run: str) -> set[str]:
    """What a live run surely has on its graph: the world's metrics and the state of each MAP whose process lives."""
    from .kill import agent_of_run
    from .spawn import read_pid_table
    try:
        table = read_pid_table(Path(run))
    except (FileNotFoundError, ValueError):
        return set()
    params = Path(run).resolve() / 'agent_params.yaml'
    return {'/metrics'} | {f'/map_{i}/state' for i, pid in table.items() if agent_of_run(pid, params)}


def _init_rclpy() -> 'StopSignals':
    """rclpy without its signal handlers: theirs end a spin with ExternalShutdownException and a traceback."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions
    from uav_flock_ros.executors import StopSignals, signals_deferred
    with signals_deferred():
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    return StopSignals()


def natural(name: str) -> list:
    """Sort key that puts /map_2 before /map_10."""
    return [int(part) if part.isdigit() else part for part in re.split(r'(\d+)', name)]


def topics(run: Optional[str], domain_id: Optional[int]) -> int:
    use_domain(run, domain_id)
    # With a run folder we know what to wait for; otherwise the list must stop growing for a while.
    expected = expected_topics(run) if run is not None else set()
    import rclpy
    stop = _init_rclpy()
    try:
        node = rclpy.create_node('uav_flock_topics')
        start = changed = time.monotonic()
        seen: list = []
        while not stop.received:
            rclpy.spin_once(node, timeout_sec=0.1)
            now_seen = node.get_topic_names_and_types()
            now = time.monotonic()
            if len(now_seen) != len(seen):
                seen, changed = now_seen, now
            # Our own node's topics are seen at once: settle only once some other participant is known.
            others = any(name not in OWN_TOPICS for name, _ in now_seen)
            complete = expected <= {name for name, _ in now_seen}
            settled = others and complete and now - start >= DISCOVERY_S and now - changed >= SETTLED_S
            quiet = not expected and not others and now - start >= QUIET_S
            if settled or quiet or now - start >= DISCOVERY_MAX_S:
                break
        node.destroy_node()
    finally:
        rclpy.try_shutdown()
    if stop.received:
        raise KeyboardInterrupt  # before the list was complete: the CLI says it was interrupted
    for name, types in sorted(seen, key=lambda nt: natural(nt[0])):
        print(f'{name} [{", ".join(types)}]')
    if not any(name not in OWN_TOPICS for name, _ in seen):
        domain = os.environ.get('ROS_DOMAIN_ID', '0')
        print(f'topics: only these two, which every node has, on ROS_DOMAIN_ID={domain}: no run there. Each run of `up` '
              'has a domain of its own: give --run RUN (its folder) or --domain-id ID (its run.json names it)',
              file=sys.stderr)
    return 0


def full_topic_name(topic: str) -> str:
    """The absolute name `ros2 topic echo` would use ('map_3/state' -> '/map_3/state'), or EchoError."""
    from rclpy.exceptions import InvalidTopicNameException
    from rclpy.expand_topic_name import expand_topic_name
    from rclpy.validate_full_topic_name import validate_full_topic_name
    try:
        name = expand_topic_name(topic, 'uav_flock_echo', '/')
        validate_full_topic_name(name)
    except (InvalidTopicNameException, ValueError) as exc:
        why = str(exc).splitlines()[0].split(', at ')[0].rstrip(':')  # rcl appends the C source line
        raise EchoError(f'{topic!r} is not a valid topic name ({why})') from None
    return name


RUN_EXTRA_TOPICS = ('/rosout', '/parameter_events', '/recorder/progress', '/run_info')
FAILURES_WAIT_S = 5.0  # how long the failure events kept by world_sim may take to come in, once it is found
# (2 s was too short once on two busy cores: echo said the MAP was killed but not when it was dropped)
WORLD_FOUND_S = 15.0  # how long discovery may take to find world_sim's writer of them on a loaded machine


def run_map(run: str, topic: str) -> tuple[Optional[int], bool]:
    """(MAP id of a /map_<id>/... topic, or None; whether the topic is one the run publishes)."""
    from . import bag
    maps = int(json.loads((Path(run) / 'run.json').read_text()).get('maps', 0))
    m = re.fullmatch(r'/map_(\d+)/\w+', topic)
    return (int(m[1]) if m else None), topic in set(bag.run_topics(maps)) | set(RUN_EXTRA_TOPICS)


def dropped_at(node: Any, map_id: int) -> Optional[tuple[int, float, str]]:
    """(step, t, cause) at which world_sim dropped a MAP, from the failure events it keeps (transient-local)."""
    import rclpy
    from uav_flock_msgs.msg import FailureEvent
    from uav_flock_ros.convert import FailureData
    from uav_flock_ros.qos import STEP_QOS
    seen: list[tuple[int, float, str]] = []

    def on_event(msg: FailureEvent) -> None:
        e = FailureData.from_msg(msg)
        if map_id in e.ids:
            seen.append((e.step, msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9, e.cause))

    sub = node.create_subscription(FailureEvent, '/events/failure', on_event, STEP_QOS)
    # The events' wait counts from when discovery found world_sim's writer: on two busy cores, finding it
    # took longer than the wait itself, and echo then said nothing of when the MAP was dropped.
    found_by, end = time.monotonic() + WORLD_FOUND_S, time.monotonic() + FAILURES_WAIT_S
    while not seen:
        now = time.monotonic()
        if sub.get_publisher_count() == 0:
            if now > found_by:
                break  # world_sim is gone too: nobody keeps the events
            end = now + FAILURES_WAIT_S
        elif now > end:
            break
        rclpy.spin_once(node, timeout_sec=0.1)
    node.destroy_subscription(sub)
    return seen[0] if seen else None


def check_in_run(node: Any, run: str, topic: str) -> None:
    """EchoError at once for a topic the run does not have, or of a MAP whose process is gone."""
    from .kill import agent_of_run
    from .spawn import read_pid_table
    map_id, known = run_map(run, topic)
    if not known:
        raise EchoError(f'{topic} is not a topic of the run in {run} (`./uav-flock topics --run {run}` lists them)')
    table = read_pid_table(Path(run)) if (Path(run) / 'pids.json').exists() else {}
    if map_id is None or map_id not in table or agent_of_run(table[map_id], Path(run).resolve() / 'agent_params.yaml'):
        return
    when = dropped_at(node, map_id)
    said = f': world_sim dropped it at t = {when[1]:.1f} s (step {when[0]}, {when[2]})' if when else ''
    raise EchoError(f'MAP {map_id} of this run was killed (its process is gone){said}; {topic} has no publisher')


def echo(topic: str, once: bool, timeout: float, run: Optional[str], domain_id: Optional[int]) -> int:
    use_domain(run, domain_id)
    topic = full_topic_name(topic)
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    stop = _init_rclpy()
    try:
        node = rclpy.create_node('uav_flock_echo')
        if run is not None:
            check_in_run(node, run, topic)
        end = time.monotonic() + timeout
        infos = []
        while time.monotonic() < end and not infos and not stop.received:
            infos = node.get_publishers_info_by_topic(topic)
            rclpy.spin_once(node, timeout_sec=0.1)
        if stop.received:
            raise KeyboardInterrupt  # while still waiting for a publisher
        if not infos:
            raise EchoError(f'no publisher of {topic} appeared within {timeout:g} s '
                            f'(ROS_DOMAIN_ID={os.environ.get("ROS_DOMAIN_ID", "0")})')
        # Like ros2cli: ask for what every publisher offers, so that no QoS mismatch hides the data.
        latched = all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos)
        reliable = all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos)
        # A transient-local publisher hands over what it keeps: --once wants the newest of it, a stream the last ten.
        qos = QoSProfile(depth=1 if once else 10,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
                         reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT)
        done = shown = False

        def show(msg: Any) -> None:
            nonlocal done, shown
            print(to_yaml(msg), flush=True)
            done, shown = once, True

        node.create_subscription(message_type(infos[0].topic_type), topic, show, qos)
        # timeout bounds the wait for the first message too: a publisher can exist and never send (the stale
        # endpoint of a SIGKILLed MAP counts as one until DDS notices it is gone).
        while not shown and not stop.received and time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.1)
        if not shown and stop.received:
            raise KeyboardInterrupt  # while still waiting for the first message
        if not shown:
            raise EchoError(f'no message on {topic} within {timeout:g} s ({len(infos)} publisher(s) known, '
                            'none sending)')
        while not done and not stop.received:  # Ctrl-C is the usual way to end an echo: exit 0, as ros2 does
            rclpy.spin_once(node, timeout_sec=0.2)
        node.destroy_node()
    finally:
        rclpy.try_shutdown()
    return 0
