"""The formation in Foxglove's schemas: what the live view serves and what `scene.mcap` holds.

One implementation of the picture, so that a recorded run opened in Foxglove (or Lichtblick) looks as it
did live. Channels, all in frame `world` with positions in m:
- `/scene` (foxglove.SceneUpdate): one entity per MAP (`map_<id>`, a sphere coloured by mode), the radio
  links within r (`links`), and a disc per cluster over the area holding 95 % of its users (`clusters`);
- `/metrics` (JSON): R_c, λ2, MAPs alive and connected components, for Foxglove's plot panel;
- `/log` (foxglove.Log): MAPs lost, as they are.
Nothing here imports ROS: the viewer node and `report` hand it numbers.
"""
from __future__ import annotations

from collections import deque
from pathlib import Path
from typing import Iterable, NamedTuple, Optional, Sequence

import numpy as np

import foxglove
from world_sim.core import records
from world_sim.core.physics import neighbour_pairs
from foxglove.channels import LogChannel, SceneUpdateChannel
from foxglove.messages import (Color, CylinderPrimitive, LinePrimitive, LinePrimitiveLineType, Log, LogLevel, Point3,
                               Pose, Quaternion, SceneEntity, SceneEntityDeletion, SceneEntityDeletionType, SceneUpdate,
                               SpherePrimitive, Timestamp, Vector3)

FRAME = 'world'
SCENE, METRICS, LOG = '/scene', '/metrics', '/log'
MAP_SIZE = 3.0  # m, the sphere drawn for a MAP
# A live step still short of a MAP's sensing this many steps on is drawn with where that MAP was last drawn
# (or, before the first whole step, not at all: the view begins with a whole formation).
LAG_STEPS = 20
# M0, M1, M2 as in the PNGs (matplotlib's tab:blue, tab:orange, tab:green)
MODE_RGBA = ((0.122, 0.467, 0.706, 1.0), (1.0, 0.498, 0.055, 1.0), (0.173, 0.627, 0.173, 1.0))
LINK_RGBA = (0.35, 0.35, 0.35, 0.8)
CLUSTER_RGBA = (0.5, 0.5, 0.5, 0.25)
METRICS_SCHEMA = {
    'type': 'object',
    'title': 'uav_flock.Metrics',
    'properties': {
        'step': {'type': 'integer', 'description': 'simulation step k'},
        't': {'type': 'number', 'description': 'simulation time (s)'},
        'coverage_ratio': {'type': 'number', 'description': 'R_c of eq. 5, 0..1'},
        'fiedler': {'type': 'number', 'description': 'lambda2 of the MAP graph Laplacian'},
        'alive': {'type': 'integer', 'description': 'MAPs still flying'},
        'components': {'type': 'integer', 'description': 'connected components of the MAP graph'},
        # Under a channel between MAPs (a scenario's links:): what they heard, world_sim/core/hearing.py.
        'usable_fiedler': {'type': 'number', 'description': 'lambda2 of the usable graph (delivery probability >= 0.5)'},
        'heard_fiedler': {'type': 'number', 'description': 'lambda2 of the heard graph (a state either way in the last 1 s)'},
        'heard_share': {'type': 'number', 'description': 'share of the neighbour states of the step heard, 0..1'},
        'oldest_used': {'type': 'integer', 'description': 'age of the oldest neighbour state a MAP used (steps)'},
    },
}


def stamp(t: float) -> Timestamp:
    sec = int(np.floor(t))
    return Timestamp(sec, int(round((t - sec) * 1e9)))


def nanoseconds(t: float) -> int:
    """Log time of simulated time t (s): the scene's clock is the simulation's, from 0."""
    return int(round(t * 1e9))


def _colour(rgba: Sequence[float]) -> Color:
    return Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def _pose(x: float, y: float, z: float) -> Pose:
    return Pose(position=Vector3(x=float(x), y=float(y), z=float(z)), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))


def formation(t: float, ids: Sequence[int], q: np.ndarray, modes: Sequence[int], r: float,
              centroids: Optional[np.ndarray] = None, radii: Optional[np.ndarray] = None,
              lost: Iterable[int] = ()) -> SceneUpdate:
    """The scene at simulated time t: the MAPs that fly (ids, positions q (n, 3), modes), their links,
    and the clusters' discs (centroids (K, 2), radii (K,); a radius of 0 is a cluster that ended). An entity
    stays in Foxglove's scene until deleted: the spheres of MAPs lost since the last scene (lost) are."""
    q = np.asarray(q, dtype=float).reshape(-1, 3)
    when = stamp(t)
    entities = [SceneEntity(timestamp=when, frame_id=FRAME, id=f'map_{int(i)}', metadata=None,
                            spheres=[SpherePrimitive(pose=_pose(*q[n]), size=Vector3(x=MAP_SIZE, y=MAP_SIZE, z=MAP_SIZE),
                                                     color=_colour(MODE_RGBA[int(modes[n]) % 3]))])
                for n, i in enumerate(ids)]
    pairs = neighbour_pairs(q, r)
    pairs = pairs[pairs[:, 0] < pairs[:, 1]]  # each link once
    entities.append(SceneEntity(timestamp=when, frame_id=FRAME, id='links', lines=[LinePrimitive(
        type=LinePrimitiveLineType.LineList, thickness=0.3, color=_colour(LINK_RGBA),
        points=[Point3(x=float(a), y=float(b), z=float(c)) for a, b, c in q[pairs.reshape(-1)]])]))
    if centroids is not None and radii is not None:
        discs = [CylinderPrimitive(pose=_pose(x, y, 0.0), size=Vector3(x=2 * float(rk), y=2 * float(rk), z=0.2),
                                   bottom_scale=1.0, top_scale=1.0, color=_colour(CLUSTER_RGBA))
                 for (x, y), rk in zip(np.asarray(centroids, dtype=float).reshape(-1, 2), radii) if rk > 0]
        entities.append(SceneEntity(timestamp=when, frame_id=FRAME, id='clusters', cylinders=discs))
    deletions = [SceneEntityDeletion(timestamp=when, type=SceneEntityDeletionType.MatchingId, id=f'map_{int(i)}')
                 for i in lost]
    return SceneUpdate(deletions=deletions, entities=entities)


def metrics(row: Sequence[float]) -> dict:
    """The metrics channel's message of one metrics.csv row (and a channel's columns, when it has them)."""
    step, t, coverage_ratio, fiedler, alive, components = row[:6]
    out = {'step': int(step), 't': float(t), 'coverage_ratio': float(coverage_ratio), 'fiedler': float(fiedler),
           'alive': int(alive), 'components': int(components)}
    if records.has_links(row):  # hearing.LINK_COLUMNS
        out.update(usable_fiedler=float(row[9]), heard_fiedler=float(row[11]), heard_share=float(row[13]),
                   oldest_used=int(row[14]))
    return out


def event(t: float, message: str, warning: bool = True) -> Log:
    return Log(timestamp=stamp(t), level=LogLevel.Warning if warning else LogLevel.Info, message=message,
               name='uav_flock')


class Frame(NamedTuple):
    """One live step, ready to draw: the MAPs (ids, positions q (n, 3)), the MAPs drawn before and not now
    (gone: their spheres to delete), the failures heard of since the last frame (MAP, cause), and the
    world's metrics row of the step."""

    t: float
    ids: list[int]
    q: np.ndarray
    gone: list[int]
    failures: list[tuple[int, str]]
    row: list[float]


class LiveSteps:
    """The live view's steps, each once its metrics and the sensing of every MAP the world counted at it
    are in. The world's topics reach a viewer each on its own (and, to one that joins late, each from its
    own history), so a step's metrics can come before its sensing, or a later step's sensing before it."""

    def __init__(self) -> None:
        self.pending: deque[list[float]] = deque()  # metrics rows of the steps not yet drawn, in order
        self.heard: dict[int, dict[int, np.ndarray]] = {}  # step -> MAP -> where the world put it
        self.last: dict[int, np.ndarray] = {}  # the MAPs of the last frame, where they were drawn
        self.failed: list[tuple[int, int, str]] = []  # (step, MAP, cause), not yet told

    def sensed(self, step: int, i: int, q: np.ndarray) -> list[Frame]:
        if not self.pending or step >= self.pending[0][0]:
            self.heard.setdefault(int(step), {})[int(i)] = np.asarray(q, dtype=float)
            if len(self.heard) > 4 * LAG_STEPS:  # sensing far ahead of the metrics: keep the newest
                del self.heard[min(self.heard)]
        return self.ready()

    def metrics(self, row: Sequence[float]) -> list[Frame]:
        self.pending.append(list(row))
        return self.ready()

    def dropped(self, step: int, ids: Iterable[int], cause: str) -> None:
        self.failed += [(int(step), int(i), cause) for i in ids]

    def ready(self) -> list[Frame]:
        out = []
        while self.pending:
            row = self.pending[0]
            k, alive = int(row[0]), int(row[4])
            at = self.heard.get(k, {})
            whole = len(at) >= alive
            if not whole and int(self.pending[-1][0]) - k < LAG_STEPS:
                break
            self.pending.popleft()
            self.heard = {s: h for s, h in self.heard.items() if s > k}
            if not whole and not self.last:
                continue
            told = [(s, i, c) for s, i, c in self.failed if s <= k and i not in at]
            self.failed = [f for f in self.failed if f not in told]
            lost = {i for _, i, _ in told}
            now = at if whole else {i: q for i, q in {**self.last, **at}.items() if i not in lost}
            ids = sorted(now)
            out.append(Frame(float(row[1]), ids, np.array([now[i] for i in ids]).reshape(-1, 3),
                             sorted(set(self.last) - set(now)), [(i, c) for _, i, c in told], row))
            self.last = now
        return out


class Channels:
    """The three channels, in one Foxglove context (a live server's, or an MCAP file's)."""

    def __init__(self, context: Optional[foxglove.Context] = None) -> None:
        self.scene = SceneUpdateChannel(SCENE, context=context)
        self.metrics = foxglove.Channel(METRICS, schema=METRICS_SCHEMA, message_encoding='json', context=context)
        self.log = LogChannel(LOG, context=context)

    def frame(self, t: float, update: SceneUpdate, figures: Optional[dict], logs: Sequence[Log]) -> None:
        """One frame at simulated time t: the scene, the metrics (None: none this step) and log entries."""
        ns = nanoseconds(t)
        self.scene.log(update, log_time=ns)
        if figures is not None:
            self.metrics.log(figures, log_time=ns)
        for entry in logs:
            self.log.log(entry, log_time=ns)


def write_mcap(path: Path, frames: Iterable[tuple[float, SceneUpdate, Optional[dict], Sequence[Log]]]) -> Path:
    """scene.mcap: each frame (t, scene, metrics or None, log entries) logged at simulated time t."""
    context = foxglove.Context()
    with foxglove.open_mcap(str(path), allow_overwrite=True, context=context):
        channels = Channels(context)
        for frame in frames:
            channels.frame(*frame)
    return path
