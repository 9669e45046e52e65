"""Record a run into a rosbag2 bag (MCAP) with the rosbags library, as `ros2 bag record -a` would.

Every message is taken serialized (raw CDR) and written as received, with the schema (ros2msg), the
RIHS01 type hash and the publishers' offered QoS of its topic. The run's fixed topics are subscribed
before the world starts stepping; any other topic that appears later is added when it is discovered.
The recorder reports on /recorder/progress the last step it holds whole, so that world_sim can keep the
run within a bounded lag of what is on disk and nothing is overwritten in a writer's history: in lockstep,
a step is whole once its /metrics and the state and command of every MAP not dropped are written (each
MAP's writer delivers in order, so its newest step says all before it are in); in realtime, where a MAP
may skip steps, once its /metrics is.
SIGINT/SIGTERM drain what is still in flight and close the bag, so an interrupted run leaves a readable one.
"""
from __future__ import annotations

import json
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any, Optional

import rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rclpy.subscription import Subscription
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from std_msgs.msg import Int64
from uav_flock_msgs.msg import FailureEvent, Metrics

from uav_flock_ros.convert import FailureData, MetricsData, stamped_id_step
from uav_flock_ros.executors import started, take_waiting
from uav_flock_ros.qos import LATCHED_QOS, is_realtime

from . import bag
from .echo import message_type

PROGRESS_TOPIC = '/recorder/progress'
RECORD_DEPTH = 1000        # reader history: room for bursts while the writer is busy on disk
DISCOVERY_PERIOD_S = 0.1   # how often the graph is looked at for topics not yet recorded
STALLED_S = 0.5            # an incomplete step with nothing arriving this long: look into the readers
DRAIN_IDLE_S = 0.3         # on shutdown, stop once nothing arrived for this long ...
DRAIN_MAX_S = 2.0          # ... or after this long in all


def _time(d: Any) -> QosTime:
    return QosTime(sec=int(d.nanoseconds // 1_000_000_000), nsec=int(d.nanoseconds % 1_000_000_000))


def offered_qos(profile: QoSProfile) -> Qos:
    """rclpy's view of a publisher's QoS as rosbags writes it into metadata.yaml."""
    return Qos(history=QosHistory(int(profile.history)), depth=int(profile.depth),
               reliability=QosReliability(int(profile.reliability)),
               durability=QosDurability(int(profile.durability)), deadline=_time(profile.deadline),
               lifespan=_time(profile.lifespan), liveliness=QosLiveliness(int(profile.liveliness)),
               liveliness_lease_duration=_time(profile.liveliness_lease_duration),
               avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions))


def reading_qos(offered: list[QoSProfile]) -> QoSProfile:
    """A reader every publisher of the topic matches, as deep as bursts need (rosbag2 adapts the same way)."""
    reliable = all(p.reliability == ReliabilityPolicy.RELIABLE for p in offered)
    latched = all(p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in offered)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=RECORD_DEPTH,
                      reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


class StepProgress:
    """The last step of which the bag holds everything: /metrics, and in lockstep each live MAP's state and
    command. A MAP dropped by the world is waited for no longer.

    A MAP counts as having reached step k only once the bag holds its messages of every step up to k: a later
    one does not vouch for an earlier one. A sample that comes late (a datagram lost and repaired, a sample left
    unannounced in its reader) holds the count, so world_sim holds within RECORDER_MAX_LAG_STEPS, well inside
    the writer's history, until it is in. Counted from the latest message, a late sample let the run go on past
    the writer's history, and a hole in the bag went unseen (once, a bag short of one command and one state at the
    step `uav-flock kill` signalled two agent processes). One that never comes holds the run for world_sim's
    RECORDER_TIMEOUT_S; then it goes on without waiting for the recorder, and says so in an error line."""

    def __init__(self, maps: int, lockstep: bool) -> None:
        self.lockstep = lockstep
        self.maps = maps
        self.metrics = -1
        self.state = [-1] * maps  # per MAP: the last step of which it and every step before are in the bag
        self.cmd = [-1] * maps
        self.early: dict[tuple[str, int], set[int]] = {}  # (kind, MAP) -> steps in the bag past a missing one
        self.reached_by: Counter[int] = Counter()  # step -> MAPs whose state and command of it are written
        self.dropped: set[int] = set()
        self.step = -1

    def map_message(self, kind: str, map_id: int, step: int) -> None:
        if not self.lockstep or not 0 <= map_id < self.maps:
            return
        before = min(self.state[map_id], self.cmd[map_id])
        last = self.state if kind == 'state' else self.cmd
        if step == last[map_id] + 1:
            last[map_id] = step
            early = self.early.get((kind, map_id))
            while early and last[map_id] + 1 in early:
                last[map_id] += 1
                early.discard(last[map_id])
        elif step > last[map_id] + 1:
            self.early.setdefault((kind, map_id), set()).add(step)
        for k in range(before + 1, min(self.state[map_id], self.cmd[map_id]) + 1):
            if k > self.step:
                self.reached_by[k] += 1

    def advance(self) -> bool:
        """Move to the last whole step; True if it moved."""
        start = self.step
        while self.step < self.metrics:
            k = self.step + 1
            if self.lockstep:
                gone = sum(1 for i in self.dropped if min(self.state[i], self.cmd[i]) < k)
                if self.reached_by[k] + gone < self.maps:
                    break
                del self.reached_by[k]
            self.step = k
        return self.step > start


class Recorder(Node):
    def __init__(self) -> None:
        super().__init__('recorder')
        for name, default in (('out', ''), ('maps', 0), ('sync', 'lockstep'), ('params_json', '{}'),
                              ('scenario_json', '{}')):
            self.declare_parameter(name, default)
        out = str(self.get_parameter('out').value)
        if not out:
            raise ValueError('parameter out (the bag folder to create) is required')
        maps = int(self.get_parameter('maps').value)
        self.expected = bag.run_topics(maps)
        self.steps = StepProgress(maps, not is_realtime(str(self.get_parameter('sync').value)))
        self.store = bag.typestore()
        self.writer = Writer(Path(out), version=9, storage_plugin=StoragePlugin.MCAP)
        self.writer.set_custom_data(bag.PARAMS_KEY, str(self.get_parameter('params_json').value))
        self.writer.set_custom_data(bag.SCENARIO_KEY, str(self.get_parameter('scenario_json').value))
        self.writer.open()
        self.subs: dict[str, Subscription] = {}
        self.skipped = {PROGRESS_TOPIC}
        self.connections: dict[str, Any] = {}
        self.last_message = time.monotonic()
        self.written = 0
        self.ready = False
        self.progress_pub = self.create_publisher(Int64, PROGRESS_TOPIC, LATCHED_QOS)
        self.create_timer(DISCOVERY_PERIOD_S, self.discover)

    def discover(self) -> None:
        """Subscribe to topics with publishers; say once when every run topic is matched."""
        for topic, types in self.get_topic_names_and_types():
            if topic in self.subs or topic in self.skipped or len(types) != 1:
                continue
            infos = self.get_publishers_info_by_topic(topic)
            if not infos:
                continue
            try:
                cls = message_type(types[0])
                msgtype = types[0]
                self.store.generate_msgdef(msgtype, ros_version=2)
            except (ImportError, AttributeError, ValueError, KeyError):
                self.get_logger().warning(f'not recording {topic}: unknown type {types[0]}')
                self.skipped.add(topic)
                continue
            offered = [i.qos_profile for i in infos]
            self.connections[topic] = self.writer.add_connection(
                topic, msgtype, typestore=self.store, offered_qos_profiles=[offered_qos(p) for p in offered])
            self.subs[topic] = self.create_subscription(
                cls, topic, lambda raw, topic=topic: self.on_message(topic, raw), reading_qos(offered), raw=True)
        if not self.ready and all(t in self.subs and self.subs[t].get_publisher_count() > 0 for t in self.expected):
            self.ready = True
            self.get_logger().info(f'recording {len(self.subs)} topics')
        if self.ready:
            # A step the world waits on that stays incomplete: the events executor may not have been told of a
            # sample that sits in its reader (seen with writers that end right after publishing); take it.
            if self.steps.step < self.steps.metrics and time.monotonic() - self.last_message > STALLED_S:
                self.take_rest()
            self.progress_pub.publish(Int64(data=self.steps.step))

    def on_message(self, topic: str, raw: bytes) -> None:
        self.writer.write(self.connections[topic], time.time_ns(), raw)
        self.written += 1
        self.last_message = time.monotonic()
        kind = topic.rsplit('/', 1)[-1]
        if kind in ('state', 'cmd') and topic.startswith('/map_'):
            self.steps.map_message(kind, *stamped_id_step(raw))
        elif topic == '/metrics':
            self.steps.metrics = MetricsData.from_msg(deserialize_message(raw, Metrics)).step
        elif topic == '/events/failure':
            self.steps.dropped.update(FailureData.from_msg(deserialize_message(raw, FailureEvent)).ids)
        else:
            return
        if self.steps.advance():
            self.progress_pub.publish(Int64(data=self.steps.step))

    def take_rest(self) -> int:
        """Write whatever is still queued in any reader, whether or not an event announced it."""
        return sum(take_waiting(sub, lambda raw, topic=topic: self.on_message(topic, raw) or True, raw=True)
                   for topic, sub in self.subs.items())

    def close(self) -> None:
        self.writer.close()


def main(argv: Optional[list[str]] = None) -> int:
    node, executor, stop = started('uav_flock_recorder', Recorder, (WriterError,), argv)
    try:
        stop.spin(executor)
        # Drain what is already on its way, then close: the bag is complete and readable.
        start = time.monotonic()
        while time.monotonic() - node.last_message < DRAIN_IDLE_S and time.monotonic() - start < DRAIN_MAX_S:
            executor.spin_once(timeout_sec=0.05)
        # The events executor can leave the last sample of a writer that died unannounced in its reader
        # (seen with an agent SIGKILLed right after publishing a command): take it all before closing.
        late = node.take_rest()
        if late:
            node.get_logger().info(f'{late} queued messages taken at shutdown')
    finally:
        node.close()
        print(json.dumps({'bag': str(node.writer.path), 'messages': node.written}), flush=True)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
