"""rosbag2 bags of uav-flock runs, read and written with the `rosbags` library (no rclpy needed).

A bag holds everything a run was: the MSDs (/users, /clusters), every MAP's sensing, state and command
at every step, the association results, the metrics and the failure events. `load` turns any such bag,
ours or one from `ros2 bag record`, sqlite3 or MCAP, into arrays; `recompute` re-derives R_c and the
Fiedler value from the raw positions with the world's own functions.
"""
from __future__ import annotations

import bisect
import json
import struct
from collections import Counter, defaultdict
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterator, Optional

import numpy as np
import yaml
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag2 import ReaderError
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from uav_agent.core.params import FlockParams
from uav_flock_ros import convert
from world_sim.core import outcome, physics, records

if TYPE_CHECKING:
    from world_sim.core.scenario import Scenario

MSG_PACKAGE = 'uav_flock_msgs'
PARAMS_KEY = 'uav_flock.params'      # custom_data key: the run's FlockParams as JSON
SCENARIO_KEY = 'uav_flock.scenario'  # custom_data key: scenario summary (maps, seed, dt, duration) as JSON

# Fixed topics of a run; per-MAP topics are /map_<id>/{sensing,state,cmd}.
GLOBAL_TOPICS = ('/clock', '/users', '/clusters', '/association', '/metrics', '/events/failure', '/events/finished',
                 '/markers')
MAP_TOPICS = ('sensing', 'state', 'cmd')


class BagError(Exception):
    """A bag that cannot be read as a uav-flock run: one line for the user."""


def run_topics(maps: int) -> list[str]:
    """Every topic a run of `maps` MAPs publishes, in a stable order."""
    return list(GLOBAL_TOPICS) + [f'/map_{i}/{t}' for i in range(maps) for t in MAP_TOPICS]


def msg_definitions(msg_dir: Optional[Path] = None) -> dict[str, Any]:
    """The uav_flock_msgs definitions as installed (share/uav_flock_msgs/msg/*.msg)."""
    if msg_dir is None:
        from ament_index_python.packages import get_package_share_directory
        msg_dir = Path(get_package_share_directory(MSG_PACKAGE)) / 'msg'
    types: dict[str, Any] = {}
    for path in sorted(msg_dir.glob('*.msg')):
        types.update(get_types_from_msg(path.read_text(), f'{MSG_PACKAGE}/msg/{path.stem}'))
    if not types:
        raise BagError(f'no message definitions in {msg_dir}')
    return types


def typestore(msg_dir: Optional[Path] = None) -> Typestore:
    """Jazzy's standard types plus ours: what rosbags needs to write schemas and RIHS01 hashes."""
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(msg_definitions(msg_dir))
    return store


@dataclass
class BagRun:
    """A run as read back from its bag; arrays follow the CSV records' column order."""

    path: Path
    counts: dict[str, int]                   # messages per topic
    metrics: np.ndarray                      # (S, 9) records.METRICS_COLUMNS (and a channel's 6), from /metrics
    trajectory: np.ndarray                   # (R, 12) records.TRAJECTORY_COLUMNS, from the states
    sensed: dict[int, dict[int, np.ndarray]]  # step -> id -> q measured by the world
    users: Optional[physics.Users]           # the MSDs and clusters before the first step
    failures: list[tuple[int, list[int], str]]  # (step, ids, cause)
    association: dict[int, tuple[np.ndarray, float]]  # step -> (map ids, recorded R_c)
    heard: dict[str, dict[int, set[int]]] = field(default_factory=dict)  # sensing|state|cmd -> step -> ids
    params: dict[str, Any] = field(default_factory=dict)
    scenario: dict[str, Any] = field(default_factory=dict)
    users_at: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # step -> (xyz, cluster)

    def users_of(self, step: int) -> Optional[physics.Users]:
        """The MSDs as last published at or before step (users that move are published every survey)."""
        if self.users is None:
            return None
        steps = sorted(self.users_at)
        i = bisect.bisect_right(steps, step)
        if i == 0:
            return self.users
        xyz, cluster = self.users_at[steps[i - 1]]
        return physics.Users(xyz, cluster, self.users.centroids, self.users.radii)

    @property
    def dt(self) -> float:
        if 'dt' in self.scenario:
            return float(self.scenario['dt'])
        m = self.metrics
        return float(m[1, 1] - m[0, 1]) if len(m) > 1 else 0.1

    @property
    def r(self) -> float:
        return float(self.params.get('r', FlockParams().r))  # a bag without our metadata: the default range


def _map_topic(topic: str) -> tuple[Optional[int], str]:
    parts = topic.strip('/').split('/')
    if len(parts) == 2 and parts[0].startswith('map_') and parts[0][4:].isdigit():
        return int(parts[0][4:]), parts[1]
    return None, topic


def _custom(path: Path, key: str) -> dict[str, Any]:
    """A JSON entry of metadata.yaml's custom_data, {} if absent (e.g. bags of `ros2 bag record`)."""
    try:
        info = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
        return dict(json.loads((info.get('custom_data') or {})[key]))
    except (OSError, KeyError, TypeError, ValueError, yaml.YAMLError):
        return {}


def recorded_sync(path: Path) -> str:
    """The sync mode the bag was recorded in; bags from before it was kept were lockstep unless said otherwise."""
    return str(_custom(find_bag(path), SCENARIO_KEY).get('sync', 'lockstep'))


def _recorded_params(path: Path) -> dict[str, Any]:
    """The agents' parameters the bag was recorded with. A bag from before `allocation` existed was made
    under Algorithm 2, so that is what its replay must run."""
    params = _custom(path, PARAMS_KEY)
    if params and 'allocation' not in params:
        params['allocation'] = 'algorithm2'
    return params


def find_bag(path: Path) -> Path:
    """The bag folder that path names: the folder itself, a run folder holding bag/, or a file in the bag.

    Users point at whichever they have at hand, as `ros2 bag info` takes the folder or its storage file.
    """
    path = Path(path)
    if not path.exists():
        raise BagError(f'{path}: no such bag')
    for candidate in ((path, path / 'bag') if path.is_dir() else (path.parent,)):
        if (candidate / 'metadata.yaml').is_file():
            return candidate
    raise BagError(f'{path}: not a rosbag2 bag (no metadata.yaml in it, nor a bag/ folder with one)')


@contextmanager
def _reader(path: Path) -> Iterator[AnyReader]:
    """An open bag; whatever rosbags finds wrong with it becomes one line for the user."""
    try:
        with AnyReader([path], default_typestore=typestore()) as reader:
            yield reader
    except (AnyReaderError, ReaderError, OSError) as exc:  # OSError: unreadable files
        raise BagError(f'{path}: not a readable rosbag2 bag ({" ".join(str(exc).split())})') from None


def deserialize(reader: AnyReader, raw: bytes, msgtype: str) -> Any:
    """A message of the bag, as rosbags reads it, but taking the bytes Fast DDS writes as they are.

    Fast CDR sizes a message for the worst-case alignment of its empty float64 sequences, so a Sensing with
    no neighbours (an isolated MAP) or a /clusters without radii carries up to 4 trailing bytes per such
    sequence; rosbags refuses more than 3 as a size mismatch. What precedes them is the whole message.
    """
    if msgtype not in reader.typestore.fielddefs or len(raw) < 4 or bytes(raw[:2]) not in (b'\x00\x00', b'\x00\x01'):
        return reader.deserialize(raw, msgtype)
    msgdef = reader.typestore.get_msgdef(msgtype)
    func = msgdef.deserialize_cdr_le if raw[1] else msgdef.deserialize_cdr_be
    try:
        message, pos = func(raw[4:], 0, msgdef.cls, reader.typestore)
    except (struct.error, UnicodeDecodeError, ValueError) as exc:
        raise BagError(f'a {msgtype} message in the bag cannot be read: {exc}') from None
    return message


def load(path: Path) -> BagRun:
    """Read a run's bag."""
    path = find_bag(path)
    with _reader(path) as reader:
        return _read(path, reader)


def _read(path: Path, reader: AnyReader) -> BagRun:
    counts: Counter[str] = Counter()
    metrics: list[list[float]] = []
    traj: list[list[float]] = []
    sensed: dict[int, dict[int, np.ndarray]] = defaultdict(dict)
    failures: list[tuple[int, list[int], str]] = []
    association: dict[int, tuple[np.ndarray, float]] = {}
    heard: dict[str, dict[int, set[int]]] = {kind: defaultdict(set) for kind in MAP_TOPICS}
    users_msgs: list[Any] = []
    clusters_msg = None
    wanted = [c for c in reader.connections if c.msgtype.startswith(f'{MSG_PACKAGE}/')]
    for conn, _, raw in reader.messages(connections=wanted):
        counts[conn.topic] += 1
        i, kind = _map_topic(conn.topic)
        msg = deserialize(reader, raw, conn.msgtype)
        if i is not None and kind in heard:
            if kind == 'state':
                st = convert.AgentStateData.from_msg(msg)
                traj.append([st.step, np.nan, st.id, *st.q, *st.p, st.mode, st.goal, st.n_users])
            elif kind == 'sensing':
                st = convert.SensingData.from_msg(msg)
                sensed[st.step][st.id] = st.q
            else:
                st = convert.CommandData.from_msg(msg)
            heard[kind][st.step].add(i)
        elif conn.topic == '/metrics':
            metrics.append(convert.MetricsData.from_msg(msg).row())
        elif conn.topic == '/events/failure':
            f = convert.FailureData.from_msg(msg)
            failures.append((f.step, list(f.ids), f.cause))
        elif conn.topic == '/association':
            a = convert.AssociationData.from_msg(msg)
            association[a.step] = (a.map_ids, a.coverage_ratio)
        elif conn.topic == '/users':
            users_msgs.append(msg)
        elif conn.topic == '/clusters' and clusters_msg is None:
            clusters_msg = msg
    if not metrics and not traj:
        if wanted:  # our topics are there, but the run never stepped
            raise BagError(f'{path}: the bag holds no steps (no /metrics and no /map_<id>/state message): '
                           'the run ended before its first step')
        raise BagError(f'{path}: no uav_flock_msgs topics: not a uav-flock run')
    m = np.array(sorted(metrics), dtype=float).reshape(len(metrics), -1) if metrics else \
        np.zeros((0, len(records.METRICS_COLUMNS)))
    run = BagRun(path=path, counts=dict(counts), metrics=m, trajectory=np.zeros((0, 12)), sensed=dict(sensed),
                 users=None, failures=sorted(failures), association=association,
                 heard={kind: dict(v) for kind, v in heard.items()},
                 params=_recorded_params(path), scenario=_custom(path, SCENARIO_KEY))
    t = np.array(sorted(traj), dtype=float).reshape(-1, len(records.TRAJECTORY_COLUMNS))
    t[:, 1] = t[:, 0] * run.dt
    run.trajectory = t
    if users_msgs and clusters_msg is not None:
        first = convert.UsersData.from_msg(users_msgs[0])
        c = convert.ClustersData.from_msg(clusters_msg)
        run.users = physics.Users(first.xyz, first.cluster, c.xy, c.radii)
        run.users_at = {u.step: (u.xyz, u.cluster) for u in map(convert.UsersData.from_msg, users_msgs)}
    return run


def recompute(run: BagRun, association: str = '3d') -> np.ndarray:
    """(step, R_c, Fiedler) per step from the positions the world measured, with the world's functions.

    Users that move are in the bag every survey period, so between two of those R_c is recomputed with
    the users as last published: exact for users that stand still, close for users that move."""
    if run.users is None:
        raise BagError(f'{run.path}: no /users or /clusters message, cannot recompute coverage')
    rows = []
    for k in sorted(run.sensed):
        ids = sorted(run.sensed[k])
        q = np.array([run.sensed[k][i] for i in ids]).reshape(-1, 3)
        assoc = physics.associate(run.users_of(k), q, run.r, association)
        pairs = physics.neighbour_pairs(q, run.r)
        rows.append([k, physics.coverage_ratio(assoc), physics.fiedler(pairs, len(ids))])
    return np.array(rows, dtype=float).reshape(-1, 3)


def first_time(t: np.ndarray, ok: np.ndarray) -> Optional[float]:
    """First time from which `ok` holds to the end of the record, or None if it does not hold at the end."""
    if len(ok) == 0 or not ok[-1]:
        return None
    bad = np.nonzero(~ok)[0]
    return float(t[bad[-1] + 1]) if len(bad) else float(t[0])


def missing_commands(run: BagRun) -> Optional[dict[int, list[int]]]:
    """Step -> MAPs whose command of that step the world used and the bag lacks; None for a realtime bag.

    In lockstep the world uses the command of every MAP it sensed at step k and did not drop during k. The
    recorder holds the run back until it has them, so only a writer that vanished first (a MAP SIGKILLed
    by hand, a host gone) can leave one out. In realtime a MAP may skip steps: nothing says what was used.
    """
    if run.scenario.get('sync', 'lockstep') != 'lockstep':
        return None
    dropped: dict[int, set[int]] = defaultdict(set)
    for step, ids, _ in run.failures:
        dropped[step].update(ids)
    commands = run.heard.get('cmd', {})
    missing = {}
    for k in run.metrics[:, 0].astype(int).tolist():
        lost = set(run.association[k][0].tolist()) - dropped[k] - commands.get(k, set()) if k in run.association \
            else set()
        if lost:
            missing[k] = sorted(lost)
    return missing


def _finite(v: float) -> Optional[float]:
    return v if np.isfinite(v) else None


def summary(run: BagRun) -> dict[str, Any]:
    """The figures a reader of a run wants first."""
    m = run.metrics
    if len(m) == 0:
        raise BagError(f'{run.path}: no /metrics messages to summarise')
    t, rc, lam2 = m[:, 1], m[:, 2], m[:, 3]
    return {
        'steps': int(len(m)),
        'duration_s': float(t[-1]),
        'maps_start': int(m[0, 4]),
        'maps_end': int(m[-1, 4]),
        'final_coverage': float(rc[-1]),
        'final_fiedler': float(lam2[-1]),
        'time_to_success_s': _finite(outcome.time_to_success(m)),
        'time_to_95_coverage_s': first_time(t, rc >= 0.95),
        'time_to_connectivity_s': first_time(t, outcome.joined(m)),
        'failures': [{'t_s': step * run.dt, 'ids': ids, 'cause': cause} for step, ids, cause in run.failures],
        'missing_commands': missing_commands(run),
        # what the run was set to do (None from a bag without our metadata): a run cut short says so
        'planned_duration_s': _number(run.scenario.get('duration')),
        'scheduled_failure': None if not run.scenario.get('fail_fraction') else
        {'t_s': _number(run.scenario.get('fail_at')), 'fraction': float(run.scenario['fail_fraction'])},
        # under a channel between MAPs (hearing.LINK_COLUMNS): what they heard, over the run
        'channel': None if not records.has_links(m) else {
            'usable_connected': float(np.mean(m[:, 9] > 0)), 'heard_connected': float(np.mean(m[:, 11] > 0)),
            'heard_share': float(m[:, 13].mean()), 'oldest_used': int(m[:, 14].max())},
    }


def _number(value: Any) -> Optional[float]:
    return None if value is None else float(value)


@dataclass
class ReplayInputs:
    """What one MAP heard during a recorded run, serialized as it was on the wire, and what it answered."""

    agent: int
    params: dict[str, Any]
    clusters: dict[int, bytes]                            # version -> raw Clusters
    sensing: dict[int, tuple[bytes, convert.SensingData]]  # step -> (raw Sensing, its values)
    states: dict[int, dict[int, bytes]]                   # MAP id -> step -> raw AgentState
    commands: dict[int, convert.CommandData]              # step -> the command recorded
    failures: list[tuple[convert.FailureData, bytes]]     # (event, raw FailureEvent), by step


def replay_inputs(path: Path, agent: int) -> ReplayInputs:
    """One MAP's recorded inputs and commands, for `replay`."""
    path = find_bag(path)
    sensing: dict[int, tuple[bytes, convert.SensingData]] = {}
    states: dict[int, dict[int, bytes]] = defaultdict(dict)
    commands: dict[int, convert.CommandData] = {}
    failures: list[tuple[convert.FailureData, bytes]] = []
    clusters: dict[int, bytes] = {}
    mine = {f'/map_{agent}/sensing', f'/map_{agent}/cmd', '/clusters', '/events/failure'}
    with _reader(path) as reader:
        wanted = [c for c in reader.connections if c.topic in mine or _map_topic(c.topic)[1] == 'state']
        for conn, _, raw in reader.messages(connections=wanted):
            raw = bytes(raw)
            i, kind = _map_topic(conn.topic)
            if kind == 'state':
                states[i][convert.stamped_id_step(raw)[1]] = raw
                continue
            msg = deserialize(reader, raw, conn.msgtype)
            if kind == 'sensing':  # said again as the messages are now (a bag from before a field came)
                sensed = convert.SensingData.from_msg(msg)
                sensing[sensed.step] = (convert.serialized(sensed, msg.header), sensed)
            elif kind == 'cmd':
                command = convert.CommandData.from_msg(msg)
                commands[command.step] = command
            elif conn.topic == '/clusters':
                clusters.setdefault(convert.ClustersData.from_msg(msg).version, raw)
            else:
                failures.append((convert.FailureData.from_msg(msg), raw))
    if not sensing and not states:
        raise BagError(f'{path}: the bag holds no steps (no /map_<id>/state message): the run ended before its '
                       'first step')
    if not sensing:
        raise BagError(f'{path}: no /map_{agent}/sensing messages: MAP {agent} is not in this bag')
    if not clusters:
        raise BagError(f'{path}: no /clusters message')
    return ReplayInputs(agent, _custom(path, PARAMS_KEY), clusters, sensing, dict(states), commands,
                        sorted(failures, key=lambda f: f[0].step))


def run_params(s: Scenario) -> dict[str, object]:
    """What every agent of a run decides with, as its bag records it for replay (PARAMS_KEY): the flock, and
    the channel between MAPs with the run's seed and step, which its decisions draw from (links.py)."""
    return {**s.flock.as_dict(), 'links': s.links.as_dict(), 'seed': s.seed, 'dt': s.dt}


def scenario_summary(path: Path, s: Scenario) -> dict[str, object]:
    """What a bag says about the run it holds, beside the agents' parameters."""
    return {'scenario': Path(path).name, 'maps': s.maps, 'seed': s.seed, 'dt': s.dt, 'duration': s.duration,
            'fail_at': s.fail_at, 'fail_fraction': s.fail_fraction, 'association': s.association,
            'vehicle': s.vehicle.model, 'separation': None if s.vehicle.ideal else s.vehicle.separation}
