"""Messages to numpy values and back: the one place where uav_flock_msgs meet the cores' arrays.

Each message type has its values as a named tuple of numbers and arrays, with `to_msg(header)` and
`from_msg(msg)`: nodes, the recorder, bag reading and replay build and read messages only through these.
The cores' own types (ClusterMap, Users, Told) are made from the values by the caller, so this package
depends on the messages alone. `from_msg` is duck-typed: it reads rclpy messages and the ones rosbags
deserializes from a bag alike.
"""
from __future__ import annotations

import math
from typing import Any, Iterable, NamedTuple, Optional

import numpy as np
from geometry_msgs.msg import Point, Vector3
from std_msgs.msg import Header
from uav_flock_msgs.msg import (AgentState, Association, Clusters, Command, FailureEvent, LinkMetrics, Metrics,
                                 NeighborList, PassedState, RoleGossip, Sensing, Traffic, Users, VehicleMetrics)


def point(v: np.ndarray) -> Point:
    return Point(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def vector(v: np.ndarray) -> Vector3:
    return Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def xyz(m: Point | Vector3) -> np.ndarray:
    return np.array([m.x, m.y, m.z])


def xyz_rows(points: Iterable[Any]) -> np.ndarray:
    """(n, 3) array of a list of points."""
    return np.array([[p.x, p.y, p.z] for p in points], dtype=float).reshape(-1, 3)


def finite(*values: Point | Vector3 | float) -> bool:
    """True if every number (or every coordinate of a Point/Vector3) is finite."""
    for v in values:
        parts: Iterable[float] = (v.x, v.y, v.z) if hasattr(v, 'x') else (v,)
        if not all(math.isfinite(float(c)) for c in parts):
            return False
    return True


class RoleGossipData(NamedTuple):
    """The `roles` block of /map_<id>/state (RoleGossip): what the demand allocation adds to a MAP's state. Field
    for field the allocation's own Gossip, which it reads by attribute, from a message or a simulated MAP alike."""

    transit: bool = False
    seen: tuple[tuple[int, int], ...] = ()      # (role code, last step a member was heard of)
    lost: tuple[tuple[float, float], ...] = ()  # key spans [lo, hi) known lost
    short: tuple[tuple[int, int], ...] = ()     # (role code, MAPs it was found short of)
    ends: tuple[float, ...] = ()                # a relay's chain ends: hops and place below, hops and place above
    settled: bool = False                       # it has reached its role's place once

    def to_msg(self) -> RoleGossip:
        return RoleGossip(in_transit=bool(self.transit), roles_heard=[int(c) for c, _ in self.seen],
                          roles_heard_step=[int(k) for _, k in self.seen],
                          lost_keys=[float(x) for span in self.lost for x in span],
                          roles_short=[int(c) for c, _ in self.short], roles_short_by=[int(n) for _, n in self.short],
                          chain_ends=[float(x) for x in self.ends], settled=bool(self.settled))

    @classmethod
    def from_msg(cls, msg: Any) -> 'RoleGossipData':
        lost = [float(x) for x in msg.lost_keys]
        return cls(bool(msg.in_transit), tuple((int(c), int(k)) for c, k in zip(msg.roles_heard, msg.roles_heard_step)),
                   tuple(zip(lost[::2], lost[1::2])),
                   tuple((int(c), int(n)) for c, n in zip(msg.roles_short, msg.roles_short_by)),
                   tuple(float(x) for x in msg.chain_ends), bool(msg.settled))


class PassedData(NamedTuple):
    """A neighbour's state of step `step` as a MAP passes it on (PassedState; AgentStateData.passed_on)."""

    id: int
    step: int
    q: np.ndarray                   # (3,) m
    p: np.ndarray                   # (3,) m/s
    n_users: int
    mode: int
    goal: int
    bridge: Optional[tuple[int, int]]  # the two clusters an M1 MAP connects, None otherwise
    achieved: tuple[int, ...]       # cluster indices known as achieved, ascending
    roles: Optional[RoleGossipData] = None  # what its allocation adds (the demand allocation's), if anything

    def fields(self) -> dict[str, Any]:
        """The message fields a state and a state passed on share."""
        return dict(id=int(self.id), step=int(self.step), position=point(self.q), velocity=vector(self.p),
                    user_count=int(self.n_users), mode=int(self.mode), goal=int(self.goal),
                    bridge=list(self.bridge) if self.bridge else [], achieved_goals=[int(k) for k in self.achieved],
                    roles=[RoleGossipData(*self.roles).to_msg()] if self.roles is not None else [])

    @classmethod
    def values(cls, msg: Any) -> tuple[Any, ...]:
        bridge = tuple(int(c) for c in msg.bridge)
        return (int(msg.id), int(msg.step), xyz(msg.position), xyz(msg.velocity), int(msg.user_count),
                int(msg.mode), int(msg.goal), (bridge[0], bridge[1]) if len(bridge) == 2 else None,
                tuple(int(k) for k in msg.achieved_goals),
                RoleGossipData.from_msg(msg.roles[0]) if len(msg.roles) else None)

    def to_msg(self) -> PassedState:
        return PassedState(**self.fields())

    @classmethod
    def from_msg(cls, msg: Any) -> 'PassedData':
        return cls(*cls.values(msg))


# /map_<id>/state's values: a state's fields (PassedData's), then the states it passes on.
_State = NamedTuple('_State', [*PassedData.__annotations__.items(), ('passed_on', 'tuple[PassedData, ...]')])
_State.__new__.__defaults__ = (None, ())


class AgentStateData(_State):
    """/map_<id>/state: what a MAP tells its neighbours at step k (PassedData's fields), and the neighbour
    states it passes on (passed_on: a lossy channel only)."""

    __slots__ = ()

    def to_msg(self, header: Header) -> AgentState:
        return AgentState(header=header, **PassedData(*self[:-1]).fields(), passed_on=[r.to_msg() for r in self.passed_on])

    @classmethod
    def from_msg(cls, msg: Any) -> 'AgentStateData':
        """A state recorded before states were passed on (a bag of an older uav-flock) passes on none."""
        return cls(*PassedData.values(msg), tuple(PassedData.from_msg(r) for r in getattr(msg, 'passed_on', ())))


class CommandData(NamedTuple):
    """/map_<id>/cmd: the control input u_i a MAP asks for at step k, and the mode and goal it decided."""

    id: int
    step: int
    u: np.ndarray                   # (3,) m/s^2
    mode: int
    goal: int
    filter: int = 0                 # what the safety filter did to u (safety.RELAXED, HELD, AWAY, RELEASED bits)

    def to_msg(self, header: Header) -> Command:
        return Command(header=header, id=int(self.id), step=int(self.step), accel=vector(self.u),
                       mode=int(self.mode), goal=int(self.goal), filter=int(self.filter))

    @classmethod
    def from_msg(cls, msg: Any) -> 'CommandData':
        """A command recorded before the filter's field (a bag of an older uav-flock) says it did nothing."""
        return cls(int(msg.id), int(msg.step), xyz(msg.accel), int(msg.mode), int(msg.goal), int(getattr(msg, 'filter', 0)))


# /map_<id>/sensing's values: a MAP's own id, step k, q (m) and p (m/s) and N_u, as PassedData declares them
# (the same quantities), then r_g, its neighbours within r and what its traffic receiver took in.
_Sensed = NamedTuple('_Sensed', [*list(PassedData.__annotations__.items())[:5], ('goal_coverage', float),
                                 ('neighbour_ids', np.ndarray), ('distances', np.ndarray), ('clusters_version', int),
                                 ('traffic_ids', np.ndarray), ('traffic_q', np.ndarray), ('traffic_p', np.ndarray)])
_Sensed.__new__.__defaults__ = (0, np.zeros(0, dtype=np.intp), np.zeros((0, 3)), np.zeros((0, 3)))


class SensingData(_Sensed):
    """/map_<id>/sensing: one MAP's own q, p, N_u and r_g at step k, its neighbours within r (neighbour_ids
    ascending, distances in m), and the broadcasts its traffic receiver took in (a multirotor's, vehicle.traffic:
    traffic_ids ascending, traffic_q (t, 3) m as each broadcasts it, traffic_p (t, 3) m/s)."""

    __slots__ = ()

    def to_msg(self, header: Header) -> Sensing:
        return Sensing(header=header, id=int(self.id), step=int(self.step), position=point(self.q),
                       velocity=vector(self.p), user_count=int(self.n_users), goal_coverage=float(self.goal_coverage),
                       clusters_version=int(self.clusters_version),
                       neighbors=NeighborList(id=int(self.id), ids=np.asarray(self.neighbour_ids, np.uint32).tolist(),
                                              distances=np.asarray(self.distances, dtype=float).tolist()),
                       traffic=Traffic(ids=np.asarray(self.traffic_ids, np.uint32).tolist(),
                                       positions=[point(v) for v in self.traffic_q],
                                       velocities=[vector(v) for v in self.traffic_p]))

    @classmethod
    def from_msg(cls, msg: Any) -> 'SensingData':
        t = getattr(msg, 'traffic', None)  # none in a bag recorded before the traffic receiver
        return cls(int(msg.id), int(msg.step), xyz(msg.position), xyz(msg.velocity), int(msg.user_count),
                   float(msg.goal_coverage), np.asarray(msg.neighbors.ids, dtype=np.intp),
                   np.asarray(msg.neighbors.distances, dtype=float), int(getattr(msg, 'clusters_version', 0)),
                   *((np.asarray(t.ids, dtype=np.intp), xyz_rows(t.positions), xyz_rows(t.velocities))
                     if t is not None else ()))


def serialized(values: Any, header: Any) -> bytes:
    """The wire bytes of a message's values (any `to_msg`) under a header read from anywhere (rclpy or a bag)."""
    from builtin_interfaces.msg import Time
    from rclpy.serialization import serialize_message
    stamp = Time(sec=int(header.stamp.sec), nanosec=int(header.stamp.nanosec))
    return serialize_message(values.to_msg(Header(stamp=stamp, frame_id=str(header.frame_id))))


class UsersData(NamedTuple):
    """/users: every MSD present at a step, and its cluster (-1: none)."""

    step: int
    xyz: np.ndarray                 # (M, 3) m
    cluster: np.ndarray             # (M,)

    def to_msg(self, header: Header) -> Users:
        return Users(header=header, step=int(self.step), positions=[point(y) for y in self.xyz],
                     cluster=np.asarray(self.cluster, np.int32).tolist())

    @classmethod
    def from_msg(cls, msg: Any) -> 'UsersData':
        return cls(int(getattr(msg, 'step', 0)), xyz_rows(msg.positions), np.asarray(msg.cluster, dtype=np.intp))


class ClustersData(NamedTuple):
    """/clusters, the survey's picture; radii None when the message has none for every cluster."""

    version: int
    xy: np.ndarray                  # (K, 2) m
    sizes: np.ndarray               # (K,)
    radii: Optional[np.ndarray]     # (K,) m
    active: np.ndarray              # (K,) bool
    velocities: np.ndarray          # (K, 2) m/s

    def to_msg(self, header: Header) -> Clusters:
        """`active` and `velocities` are left empty when every cluster exists and stands still, as before
        users could move."""
        v = self.velocities
        moving = v is not None and np.any(v)
        return Clusters(header=header, version=int(self.version),
                        centroids=[point(np.array([c[0], c[1], 0.0])) for c in self.xy],
                        sizes=np.asarray(self.sizes, np.uint32).tolist(),
                        radii=[] if self.radii is None else np.asarray(self.radii, dtype=float).tolist(),
                        active=[] if self.active is None or np.all(self.active) else [bool(a) for a in self.active],
                        velocities=[vector(np.array([w[0], w[1], 0.0])) for w in v] if moving else [])

    @classmethod
    def from_msg(cls, msg: Any) -> 'ClustersData':
        xy = xyz_rows(msg.centroids)[:, :2]
        radii = np.asarray(getattr(msg, 'radii', []), dtype=float)
        active = np.asarray(getattr(msg, 'active', []), dtype=bool)
        vel = getattr(msg, 'velocities', [])
        return cls(int(getattr(msg, 'version', 0)), xy, np.asarray(msg.sizes, dtype=np.intp),
                   radii if len(radii) == len(xy) else None,
                   active if len(active) == len(xy) else np.ones(len(xy), dtype=bool),
                   xyz_rows(vel)[:, :2] if len(vel) == len(xy) else np.zeros((len(xy), 2)))


class AssociationData(NamedTuple):
    """/association: the live MAPs of a step, their N_u, each cluster's coverage and R_c."""

    step: int
    map_ids: np.ndarray
    user_counts: np.ndarray
    cluster_coverage: np.ndarray
    coverage_ratio: float

    def to_msg(self, header: Header) -> Association:
        return Association(header=header, step=int(self.step), map_ids=np.asarray(self.map_ids, np.uint32).tolist(),
                           user_counts=np.asarray(self.user_counts, np.uint32).tolist(),
                           cluster_coverage=np.asarray(self.cluster_coverage, dtype=float).tolist(),
                           coverage_ratio=float(self.coverage_ratio))

    @classmethod
    def from_msg(cls, msg: Any) -> 'AssociationData':
        return cls(int(msg.step), np.asarray(msg.map_ids, dtype=np.intp), np.asarray(msg.user_counts, dtype=np.intp),
                   np.asarray(msg.cluster_coverage, dtype=float), float(msg.coverage_ratio))


class MetricsData(NamedTuple):
    """/metrics: one row of metrics.csv (records.METRICS_COLUMNS, then under a channel hearing.LINK_COLUMNS, then on
    a multirotor records.VEHICLE_COLUMNS)."""

    step: int
    t: float
    coverage_ratio: float
    fiedler: float
    alive: int
    components: int
    mode0: int
    mode1: int
    mode2: int
    # Under a channel: usable_fiedler, usable_components, heard_fiedler, heard_components, heard_share, oldest_used.
    links: Optional[tuple[float, int, float, int, float, int]] = None
    # On a multirotor: min_distance, power, energy, relaxed, held.
    vehicle: Optional[tuple[float, float, float, int, int]] = None

    @classmethod
    def of_row(cls, row: Iterable[float]) -> 'MetricsData':
        k, t, rc, lam2, alive, comp, m0, m1, m2, *rest = row
        heard = rest[:len(LINK_FIELDS)] if len(rest) in (len(LINK_FIELDS), len(LINK_FIELDS) + len(VEHICLE_FIELDS)) else []
        flown = rest[len(heard):]
        links = None if not heard else (float(heard[0]), int(heard[1]), float(heard[2]), int(heard[3]),
                                        float(heard[4]), int(heard[5]))
        vehicle = None if not flown else (float(flown[0]), float(flown[1]), float(flown[2]), int(flown[3]), int(flown[4]))
        return cls(int(k), float(t), float(rc), float(lam2), int(alive), int(comp), int(m0), int(m1), int(m2), links,
                   vehicle)

    def row(self) -> list[float]:
        """The metrics.csv row."""
        return [*self[:9], *(self.links or ()), *(self.vehicle or ())]

    def to_msg(self, header: Header) -> Metrics:
        heard = [] if self.links is None else [LinkMetrics(**dict(zip(LINK_FIELDS, self.links)))]
        flown = [] if self.vehicle is None else [VehicleMetrics(**dict(zip(VEHICLE_FIELDS, self.vehicle)))]
        return Metrics(header=header, **{f: getattr(self, f) for f in self._fields[:9]}, links=heard, vehicle=flown)

    @classmethod
    def from_msg(cls, msg: Any) -> 'MetricsData':
        links = None
        if len(msg.links):
            h = msg.links[0]
            links = (float(h.usable_fiedler), int(h.usable_components), float(h.heard_fiedler), int(h.heard_components),
                     float(h.heard_share), int(h.oldest_used))
        vehicle = None
        flown = getattr(msg, 'vehicle', ())  # absent from bags recorded before the field: their type is in the bag
        if len(flown):
            v = flown[0]
            vehicle = (float(v.min_distance), float(v.power), float(v.energy), int(getattr(v, 'relaxed', 0)),
                       int(getattr(v, 'held', 0)))  # both absent from bags recorded before the filter's counts
        return cls(int(msg.step), float(msg.t), float(msg.coverage_ratio), float(msg.fiedler), int(msg.alive),
                   int(msg.components), int(msg.mode0), int(msg.mode1), int(msg.mode2), links, vehicle)


LINK_FIELDS = ('usable_fiedler', 'usable_components', 'heard_fiedler', 'heard_components', 'heard_share', 'oldest_used')
VEHICLE_FIELDS = ('min_distance', 'power', 'energy', 'relaxed', 'held')  # records.VEHICLE_COLUMNS


class FailureData(NamedTuple):
    """/events/failure: MAPs the world dropped at a step, and why ("scheduled" or "killed")."""

    step: int
    ids: tuple[int, ...]
    cause: str

    def to_msg(self, header: Header) -> FailureEvent:
        return FailureEvent(header=header, step=int(self.step), ids=[int(i) for i in self.ids], cause=str(self.cause))

    @classmethod
    def from_msg(cls, msg: Any) -> 'FailureData':
        return cls(int(msg.step), tuple(int(i) for i in msg.ids), str(msg.cause))


def stamped_id_step(raw: bytes) -> tuple[int, int]:
    """(id, step) of a serialized AgentState or Command, read from its CDR bytes without deserializing.

    Both begin with a Header, then `uint32 id` and `uint64 step`; the recorder reads these two fields of
    every MAP's message at each step, and a full deserialization costs about ten times more.
    """
    order = 'little' if raw[1] & 1 else 'big'  # encapsulation kind: CDR_LE or CDR_BE
    body = memoryview(raw)[4:]                  # CDR alignment counts from after the 4-byte encapsulation
    at = 8 + 4 + int.from_bytes(body[8:12], order)  # stamp (sec, nanosec), frame_id's length and characters
    at += -at % 4
    map_id = int.from_bytes(body[at:at + 4], order)
    at += 4
    at += -at % 8
    return map_id, int.from_bytes(body[at:at + 8], order)
