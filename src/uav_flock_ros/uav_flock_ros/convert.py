"""Messages to numpy values and back: the one place where uav_flock_msgs meet the cores' arrays.

Builders take arrays and numbers, readers return them; the cores' own types (ClusterMap, Users, Told) are
made from those by the caller, so this package depends on the messages alone. The readers are
duck-typed: they read rclpy messages and the ones rosbags deserializes from a bag alike.
"""
from __future__ import annotations

import math
from typing import Any, Iterable, NamedTuple, Optional

import numpy as np
from geometry_msgs.msg import Point, Vector3
from std_msgs.msg import Header
from uav_flock_msgs.msg import AgentState, Association, Clusters, NeighborList, Sensing, Users


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


def role(msg: AgentState) -> tuple[int, int, Optional[tuple[int, int]]]:
    """(mode, goal, bridge) a neighbour's state states; bridge None unless it names two clusters."""
    bridge = tuple(int(c) for c in msg.bridge)
    return int(msg.mode), int(msg.goal), (bridge[0], bridge[1]) if len(bridge) == 2 else None


def users(header: Header, step: int, xyz_all: np.ndarray, cluster: np.ndarray) -> Users:
    return Users(header=header, step=int(step), positions=[point(y) for y in xyz_all],
                 cluster=np.asarray(cluster, np.int32).tolist())


def users_arrays(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    """(positions (M, 3) in m, cluster id per MSD, -1 for none)."""
    return xyz_rows(msg.positions), np.asarray(msg.cluster, dtype=np.intp)


def clusters(header: Header, version: int, centroids: np.ndarray, sizes: np.ndarray, radii: np.ndarray,
             active: Optional[np.ndarray] = None, velocities: Optional[np.ndarray] = None) -> Clusters:
    """The survey's clusters; `active` and `velocities` are left empty when every cluster exists and stands
    still, as before users could move."""
    moving = velocities is not None and np.any(velocities)
    return Clusters(header=header, version=int(version),
                    centroids=[point(np.array([c[0], c[1], 0.0])) for c in centroids],
                    sizes=np.asarray(sizes, np.uint32).tolist(), radii=np.asarray(radii, dtype=float).tolist(),
                    active=[] if active is None or np.all(active) else [bool(a) for a in active],
                    velocities=[vector(np.array([v[0], v[1], 0.0])) for v in velocities] if moving else [])


class ClusterArrays(NamedTuple):
    """A /clusters message as arrays; radii None when the message has none for every cluster."""

    version: int
    xy: np.ndarray                  # (K, 2) m
    sizes: np.ndarray               # (K,)
    radii: Optional[np.ndarray]     # (K,) m
    active: np.ndarray              # (K,) bool
    velocities: np.ndarray          # (K, 2) m/s


def clusters_arrays(msg: Any) -> ClusterArrays:
    xy = xyz_rows(msg.centroids)[:, :2]
    radii = np.asarray(getattr(msg, 'radii', []), dtype=float)
    active = np.asarray(getattr(msg, 'active', []), dtype=bool)
    vel = getattr(msg, 'velocities', [])
    return ClusterArrays(int(getattr(msg, 'version', 0)), xy, np.asarray(msg.sizes, dtype=np.intp),
                         radii if len(radii) == len(xy) else None,
                         active if len(active) == len(xy) else np.ones(len(xy), dtype=bool),
                         xyz_rows(vel)[:, :2] if len(vel) == len(xy) else np.zeros((len(xy), 2)))


def association(header: Header, step: int, ids: np.ndarray, n_users: np.ndarray, cluster_coverage: np.ndarray,
                coverage_ratio: float) -> Association:
    return Association(header=header, step=int(step), map_ids=np.asarray(ids, np.uint32).tolist(),
                       user_counts=np.asarray(n_users, np.uint32).tolist(),
                       cluster_coverage=np.asarray(cluster_coverage, dtype=float).tolist(),
                       coverage_ratio=float(coverage_ratio))


def sensing(header: Header, map_id: int, step: int, q: np.ndarray, p: np.ndarray, n_users: int,
            goal_coverage: float, neighbour_ids: np.ndarray, neighbour_q: np.ndarray,
            clusters_version: int = 0) -> Sensing:
    """One MAP's sensing of a step: its own q, p, N_u and r_g, and its neighbours with their distances."""
    return Sensing(header=header, id=int(map_id), step=int(step), position=point(q), velocity=vector(p),
                   user_count=int(n_users), goal_coverage=float(goal_coverage),
                   clusters_version=int(clusters_version),
                   neighbors=NeighborList(id=int(map_id), ids=np.asarray(neighbour_ids, np.uint32).tolist(),
                                          distances=np.linalg.norm(neighbour_q - q, axis=1).tolist()))


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
