"""How a run ended, judged the same way by the layout benchmark, the tests and the docs.

Success: covered (mean R_c >= 95 %) and connected (one component: lambda2 > 0, or a single MAP) at every step
over the last 10 s.
Where the MAPs ended is read geometrically, so every policy set is judged by one rule: a MAP serves the
cluster whose 95 % disc (widened by the ground radius) holds it, else relays on the MST edge within r of
it, else it is astray.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uav_agent.core.clusters import mst_edges, segment_distance

from . import layouts, vehicle
from .records import METRICS_COLUMNS, TRAJECTORY_COLUMNS
from .scenario import Scenario

R_C, T, ALIVE, COMPONENTS = (METRICS_COLUMNS.index(c) for c in ('coverage_ratio', 't', 'alive', 'components'))
COVERED = 0.95
TAIL = 10.0  # s


@dataclass(frozen=True)
class Outcome:
    success: bool
    time_to_success: float            # first t with R_c >= 95 % and one network (s), inf if never
    final_coverage: float             # mean R_c over the tail
    connected_tail: bool              # one network at every step of the tail
    per_cluster: tuple[int, ...]      # MAPs ending at each cluster
    per_edge: tuple[int, ...]         # MAPs ending on each MST edge of the layout's floor
    astray: int                       # MAPs ending elsewhere
    in_m0: int                        # MAPs whose last mode is M0


def joined(metrics: np.ndarray, components: int = COMPONENTS) -> np.ndarray:
    """Per step, whether the MAPs flying form one network: one component of at least one MAP. For two or more
    that is lambda2 > 0; a single MAP, whose lambda2 is 0, is a network too. components: the column counted
    (the disc graph's, or under a channel the usable graph's, hearing.LINK_COLUMNS)."""
    return (metrics[:, components] == 1) & (metrics[:, ALIVE] >= 1)


def time_to_success(metrics: np.ndarray) -> float:
    """Time to success, the one definition every figure uses: the first t with R_c >= 95 % and the MAPs one
    network (joined: lambda2 > 0, or a single MAP) (s), inf if never."""
    good = (metrics[:, R_C] >= COVERED) & joined(metrics)
    return float(metrics[np.argmax(good), T]) if good.any() else float('inf')


def judge(s: Scenario, metrics: np.ndarray, trajectory: np.ndarray) -> Outcome:
    t = metrics[:, T]
    tail = t >= t[-1] - TAIL + 1e-9
    cov = float(metrics[tail, R_C].mean())
    connected = bool(np.all(joined(metrics)[tail]))
    first = time_to_success(metrics)
    step = trajectory[:, TRAJECTORY_COLUMNS.index('step')]
    last = trajectory[step == step.max()]
    xy = last[:, [TRAJECTORY_COLUMNS.index('x'), TRAJECTORY_COLUMNS.index('y')]]
    mode = last[:, TRAJECTORY_COLUMNS.index('mode')]
    per_cluster, per_edge, astray = place(s, xy)
    return Outcome(cov >= COVERED and connected, first, cov, connected, per_cluster, per_edge, astray,
                   int(np.count_nonzero(mode == 0)))


def t_star(s: Scenario, centroids: np.ndarray) -> float:
    """T*, the physical bound on a time to success (s): the largest, over clusters, of the least time a MAP at rest
    at the nearest point of the release square needs, within the vehicle's v_max and a_max, to come to rest where
    its coverage disc (ground radius rho) reaches the cluster's centroid. Clusters whose users appear later are left
    out: a first success is counted among those there at the release. Infinite on the paper's vehicle."""
    if s.vehicle.ideal:
        return float('inf')
    centre, half = np.asarray(s.release_center), s.release_half_width
    rho = layouts.ground_radius(s)
    there = [c for c, cluster in zip(np.asarray(centroids), s.clusters) if cluster.start <= 0.0]
    far = max(float(np.linalg.norm(c - np.clip(c, centre - half, centre + half))) - rho for c in there)
    return vehicle.least_time(far, s.vehicle.v_max, s.vehicle.a_max)


def flown(trajectory: np.ndarray, dt: float) -> tuple[float, float]:
    """The top speed (m/s) and the top acceleration (m/s^2) over the ground of any MAP, read from trajectory rows
    (TRAJECTORY_COLUMNS: a MAP's velocity from one step to the next, wherever it was recorded at both)."""
    col = {c: trajectory[:, i] for i, c in enumerate(TRAJECTORY_COLUMNS)}
    v = np.column_stack([col['vx'], col['vy'], col['vz']])
    order = np.lexsort((col['step'], col['id']))
    same = (np.diff(col['id'][order]) == 0) & (np.diff(col['step'][order]) == 1)
    dv = np.diff(v[order], axis=0)[same]
    top_a = float(np.linalg.norm(dv, axis=1).max() / dt) if len(dv) else 0.0
    return float(np.linalg.norm(v, axis=1).max()) if len(v) else 0.0, top_a


def flight_summary(s: Scenario, metrics: np.ndarray, trajectory: np.ndarray, centroids: np.ndarray) -> str:
    """A multirotor's run in a line: how it flew (from the records, not the code), what it cost, and its time to
    success against T*."""
    from .records import vehicle_column
    speed, accel = flown(trajectory, s.dt)
    least = vehicle_column(metrics, 'min_distance')
    power = vehicle_column(metrics, 'power')
    energy = vehicle_column(metrics, 'energy')
    bound, first = t_star(s, centroids), time_to_success(metrics)
    success = (f'success at {first:.1f} s = {first / bound:.2f} T*' if np.isfinite(first) else 'no success') \
        + f' (T* = {bound:.1f} s)'
    return (f'least distance {np.nanmin(least):.2f} m (separation {s.vehicle.separation:g} m), top speed {speed:.1f} '
            f'm/s, top acceleration {accel:.2f} m/s^2; mean power {power.mean():.1f} W (hover '
            f'{vehicle.HOVER:.1f} W), energy {energy[-1] / 1e3:.1f} kJ; {success}')


def place(s: Scenario, xy: np.ndarray) -> tuple[tuple[int, ...], tuple[int, ...], int]:
    """(MAPs per cluster, MAPs per MST edge, MAPs astray) for MAP positions xy."""
    centres = np.array([c.center for c in s.clusters], dtype=float)
    reach = np.array([layouts.disc95(c.spread) for c in s.clusters]) + layouts.ground_radius(s)
    dist = np.linalg.norm(xy[:, None, :] - centres[None, :, :], axis=-1)
    inside = dist <= reach[None, :]
    nearest = np.argmin(np.where(inside, dist, np.inf), axis=1)
    at_cluster = inside.any(axis=1)
    per_cluster = np.bincount(nearest[at_cluster], minlength=len(centres))
    edges = mst_edges(centres)
    rest = xy[~at_cluster]
    per_edge = np.zeros(len(edges), dtype=int)
    astray = 0
    for point in rest:
        d = [segment_distance(point, centres[a], centres[b]) for a, b in edges]
        if d and min(d) <= s.flock.r:
            per_edge[int(np.argmin(d))] += 1
        else:
            astray += 1
    return tuple(int(v) for v in per_cluster), tuple(int(v) for v in per_edge), astray

