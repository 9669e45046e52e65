"""Where the MSDs are at each step when they move: clusters that drift or follow waypoints, arrive or
leave, and users that walk on their own (docs/dynamics.md)."""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from .scenario import Cluster, Scenario

F64 = NDArray[np.float64]


def center_at(c: Cluster, t: float) -> F64:
    """The centre of cluster c at time t: still before its start, then drifting or flying its waypoints."""
    tau = max(t - c.start, 0.0)
    if not c.waypoints:
        return np.asarray(c.center, dtype=float) + np.asarray(c.velocity, dtype=float) * tau
    pts = np.array([c.center, *c.waypoints], dtype=float)
    reach = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))]
    s = tau * c.speed
    if s >= reach[-1]:
        return pts[-1]
    i = int(np.searchsorted(reach, s, side='right')) - 1  # reach[i] <= s < reach[i + 1]: a leg of length > 0
    return pts[i] + (s - reach[i]) / (reach[i + 1] - reach[i]) * (pts[i + 1] - pts[i])


class Crowd:
    """The MSDs of a scenario whose users move, from their first draw (physics.make_users).

    Each MSD keeps its place in its cluster (its offset at the draw), follows its cluster's centre and adds
    its own random walk, drawn from a stream of its own so that motion never shifts another draw.
    """

    def __init__(self, s: Scenario, xy0: F64, cluster: NDArray[np.intp], rng: np.random.Generator) -> None:
        self.s = s
        self.cluster = cluster
        self.offset = xy0 - np.array([c.center for c in s.clusters], dtype=float).reshape(-1, 2)[cluster]
        self.start = np.array([c.start for c in s.clusters])[cluster]
        self.end = np.array([math.inf if c.end is None else c.end for c in s.clusters])[cluster]
        walk = np.array([c.walk for c in s.clusters])[cluster]
        self.walkers = np.flatnonzero(walk > 0)
        self.walk_step = walk[self.walkers] * math.sqrt(s.dt)
        self.rng = rng

    def at(self, k: int) -> tuple[F64, NDArray[np.bool_]]:
        """(xy (M, 2), present (M,)) at step k: an MSD is present from its cluster's start to its end."""
        t = k * self.s.dt
        centers = np.array([center_at(c, t) for c in self.s.clusters]).reshape(-1, 2)
        return centers[self.cluster] + self.offset, (self.start <= t + 1e-9) & (t + 1e-9 < self.end)

    def walk(self) -> None:
        """One step of every walking MSD's random walk (Gaussian, walk * sqrt(dt) per axis)."""
        if len(self.walkers):
            self.offset[self.walkers] += self.rng.normal(size=(len(self.walkers), 2)) * self.walk_step[:, None]


def events(s: Scenario) -> list[tuple[float, str]]:
    """(time, what) of every arrival and departure, for plots and the benchmark's tables."""
    out = []
    for k, c in enumerate(s.clusters):
        if c.start > 0:
            out.append((c.start, f'cluster {k} arrives'))
        if c.end is not None:
            out.append((c.end, f'cluster {k} leaves'))
    return sorted(out)
