"""The kinds of motion and loss a run of a study (and benchmarks/bench_motion.py) flies on a layout, and the
figures one run yields: one place for both, so that a study reproduces the benchmark run by run."""
from __future__ import annotations

import dataclasses
import math
from typing import Any, Optional

import numpy as np

from uav_agent.core.clusters import mst_edges
from uav_agent.core.state import M1
from world_sim.core import layouts
from world_sim.core import records
from world_sim.core.outcome import COVERED, R_C, joined
from world_sim.core.records import METRICS_COLUMNS
from world_sim.core.scenario import Cluster, Scenario

from ..batch import BatchSimulator

EVENT_S = {'loss': 45.0, 'wipeout': 45.0, 'arrival': 40.0}
STATIC_S = 60.0
# Each kind's own stream of random draws, numbered as the benchmarks always numbered them, so that a study
# and a benchmark fly the same runs: the case's choices come from draws(...), those made in flight (the role
# a wipe-out takes) from draws(...) + IN_FLIGHT. Drift at 1, 2 or 3 m/s each has its own; other speeds 2's.
DRAW = {'drift1': 0, 'drift2': 1, 'drift3': 2, 'crossing': 3, 'loss': 4, 'wipeout': 5, 'arrival': 6, 'static': 9}
IN_FLIGHT = 7
HELD_S = 10.0  # a run "ends covered and connected" when it is so over its last HELD_S
# The figures of one run (figures()): its first step covered (R_c >= 95 %) and connected, the share of time
# connected after it, how many times the network fell apart after it (splits), the longest outage after it, mean
# R_c after it, time from the event to covered and connected again, whether it ends covered and connected over
# HELD_S, and R_c and components at the end; and the share of time after it that the disc graph is connected.
# Connected is lambda2 > 0 of the usable graph: the disc graph under the paper's channel; under a `links:` channel
# the links that deliver half of what is sent over them (docs/links.md), of which the disc graph is the share `disc`.
FIGURES = ('converged', 'connected', 'splits', 'outage', 'rc', 'recovery', 'ends_ok', 'end_rc', 'end_components',
           'disc', *('t_star', 'least_distance', 'top_speed', 'top_accel', 'power', 'energy', 'relaxed', 'held',
                     'formed', 'connected_formed', 'held_longest', 'released'))
# A multirotor's (docs/vehicle.md; None on the ideal vehicle): T* (s), the least distance between two MAPs (m),
# the top speed (m/s) and acceleration (m/s^2) over the ground read from the trajectory, the formation's mean
# power per MAP after convergence (W; over the whole run if it never converged), the energy it drew (J), the
# shares of MAP-steps whose safety filter relaxed a protected link and that a protected link held back (0 under
# the rules), and the first step the formation is formed (covered, connected and every MAP slower than
# FORMED_SPEED) with the share of time connected after it (None if it never formed). A multirotor's formation
# first counts as converged while MAPs still fly to their roles at up to v_max, joined at that step by some of
# them only passing by; `connected` counts from that step, `connected_formed` from the formation at rest.
# Under the safety filter, rule 'release' (safety.held_next): the longest any MAP was held back from its goal
# without a break (s), and the share of MAP-steps free of their protected links.
FORMED_SPEED = 3.0  # m/s over the ground: a formation is formed once every MAP flies slower (hovering in gusts: < 1)


def lb_along(s: Scenario, until: float) -> int:
    """The largest floor LB of the layout as its drifting clusters move, sampled every 5 s."""
    most = 0
    for t in np.arange(0.0, until + 1e-9, 5.0):
        moved = tuple(dataclasses.replace(c, center=(c.center[0] + c.velocity[0] * t, c.center[1] + c.velocity[1] * t))
                      for c in s.clusters)
        most = max(most, layouts.floor(dataclasses.replace(s, clusters=moved)).total)
    return most


def draws(layout: int, seed: int, kind: str, value: Optional[float] = None) -> int:
    """The seed of a run's own draws: layout n, run seed, kind (drift with value: its speed)."""
    if kind == 'drift':
        kind = f'drift{2.0 if value is None else value:g}'
    return layout * 1000 + seed * 10 + DRAW.get(kind, DRAW['drift2'])


def case(kind: str, lay: Scenario, seed: int, rng: np.random.Generator, value: Optional[float] = None) -> Scenario:
    """The scenario of one run of a kind on a layout, its random choices drawn from rng, N by the kind's rule.

    kind: static (the layout still, STATIC_S, N = ceil(1.5 x LB)), drift (value: speed, m/s), crossing,
    arrival, loss (value: the share of MAPs that fail), wipeout; bench_motion's drift1/2/3 are drift at 1, 2, 3 m/s.
    """
    if kind.startswith('drift') and kind != 'drift':
        kind, value = 'drift', float(kind[len('drift'):])
    s = dataclasses.replace(lay, seed=seed, survey='online')
    if kind == 'static':
        s = dataclasses.replace(s, duration=STATIC_S)
        return dataclasses.replace(s, maps=math.ceil(1.5 * layouts.floor(s).total))
    clusters = list(s.clusters)
    if kind == 'drift':
        heading = rng.uniform(0, 2 * math.pi)
        speed = 2.0 if value is None else value
        c = int(rng.integers(len(clusters)))
        clusters[c] = dataclasses.replace(clusters[c], velocity=(round(speed * math.cos(heading), 3),
                                                                 round(speed * math.sin(heading), 3)))
    elif kind == 'crossing':
        a, b = mst_edges(np.array([c.center for c in clusters]))[int(rng.integers(len(clusters) - 1))]
        ca, cb = np.array(clusters[a].center), np.array(clusters[b].center)
        v = (cb - ca) * 2.0 / 90.0  # each is at the other's place at 45 s and as far beyond by 90 s
        clusters[a] = dataclasses.replace(clusters[a], velocity=(round(v[0], 3), round(v[1], 3)))
        clusters[b] = dataclasses.replace(clusters[b], velocity=(round(-v[0], 3), round(-v[1], 3)))
    elif kind == 'arrival':
        xy = np.array([c.center for c in clusters])
        mid = xy.mean(axis=0)
        heading = rng.uniform(0, 2 * math.pi)
        u = np.array([math.cos(heading), math.sin(heading)])
        far = float(np.max(xy @ u - mid @ u))
        at = mid + u * (far + rng.uniform(100.0, 150.0))
        clusters.append(Cluster(center=(round(at[0], 1), round(at[1], 1)), spread=14.0, size=300,
                                start=EVENT_S['arrival']))
    s = dataclasses.replace(s, clusters=tuple(clusters))
    if kind in ('loss', 'wipeout'):
        s = dataclasses.replace(s, duration=120.0, maps=math.ceil(1.8 * layouts.floor(s).total))
        if kind == 'loss':
            s = dataclasses.replace(s, fail_at=EVENT_S['loss'], fail_fraction=0.3 if value is None else value)
        return s
    if kind == 'arrival':
        return dataclasses.replace(s, duration=100.0, maps=math.ceil(1.5 * layouts.floor(s).total))
    return dataclasses.replace(s, duration=90.0, maps=math.ceil(1.5 * lb_along(s, 90.0)))


def wipe_out(sim: BatchSimulator, rng: np.random.Generator) -> int:
    """Drop every live MAP of one role picked at random: a cluster's servers or an edge's relays."""
    roles: dict[tuple, list[int]] = {}
    for i in np.flatnonzero(sim.alive).tolist():
        m = sim.memory[i]
        roles.setdefault(('edge', m.bridge) if m.mode == M1 and m.bridge else ('cluster', m.goal), []).append(i)
    keys = sorted(roles, key=str)
    ids = roles[keys[int(rng.integers(len(keys)))]]
    sim.world.drop(np.array(ids))
    return len(ids)


def wipe_at(kind: str, sim: BatchSimulator, rng: np.random.Generator) -> None:
    """Before a step: the wipe-out of a wipeout run, at its time."""
    if kind == 'wipeout' and abs(sim.world.k * sim.scenario.dt - EVENT_S['wipeout']) < sim.scenario.dt / 2:
        wipe_out(sim, rng)


def outage_s(down: np.ndarray, dt: float) -> float:
    """The longest run of True in down, in seconds."""
    longest = run = 0
    for d in down.tolist():
        run = run + 1 if d else 0
        longest = max(longest, run)
    return longest * dt


def flight_figures(s: Scenario, m: np.ndarray, trajectory: np.ndarray, centroids: np.ndarray,
                   converged: Optional[float]) -> dict[str, Optional[float]]:
    """FIGURES of a multirotor's run (records.VEHICLE_COLUMNS and the trajectory); none on the ideal vehicle."""
    if s.vehicle.ideal:
        return {}
    from world_sim.core import outcome
    speed, accel = outcome.flown(trajectory, s.dt)
    after = m[:, 1] >= (converged if converged is not None else 0.0)
    return {'t_star': outcome.t_star(s, centroids), 'least_distance': float(np.nanmin(records.vehicle_column(m, 'min_distance'))),
            'top_speed': speed, 'top_accel': accel, 'power': float(records.vehicle_column(m, 'power')[after].mean()),
            'energy': float(records.vehicle_column(m, 'energy')[-1]),
            **{name: float(records.vehicle_column(m, name).sum() / max(m[:, 4].sum(), 1.0)) for name in ('relaxed', 'held')},
            **formation(m, trajectory)}


def liveness_figures(s: Scenario, world: Any, m: np.ndarray) -> dict[str, float]:
    """'held_longest' and 'released' of a multirotor's run from its world (model.World); none on the ideal vehicle."""
    if s.vehicle.ideal:
        return {}
    return {'held_longest': world.away_longest * s.dt, 'released': world.released / max(float(m[:, 4].sum()), 1.0)}


def usable(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per metrics row, whether the run is covered (R_c >= 95 %) and connected, and whether it is connected: the
    usable graph's components, which are the disc graph's under the paper's channel."""
    connected = joined(m, len(METRICS_COLUMNS) + 1) if records.has_links(m) else joined(m)
    return (m[:, R_C] >= COVERED) & connected, connected


def formation(m: np.ndarray, trajectory: np.ndarray) -> dict[str, float]:
    """'formed', the first step covered, connected and with every MAP slower than FORMED_SPEED (s), and
    'connected_formed', the share of time connected from it on; neither if the formation never formed."""
    ok, connected = usable(m)
    at = np.flatnonzero(ok & (top_speeds(m, trajectory) < FORMED_SPEED))
    return {'formed': float(m[at[0], 1]), 'connected_formed': float(connected[at[0]:].mean())} if len(at) else {}


def top_speeds(m: np.ndarray, trajectory: np.ndarray) -> np.ndarray:
    """Per metrics row, the fastest MAP's speed over the ground (m/s) at that step; inf at a step the trajectory
    did not record."""
    col = records.TRAJECTORY_COLUMNS.index
    step = trajectory[:, col('step')].astype(np.intp)
    speed = np.linalg.norm(trajectory[:, col('vx'):col('vz') + 1], axis=1)
    top = np.full(int(max(step.max(initial=0), m[:, 0].max(initial=0))) + 1, -np.inf)
    np.maximum.at(top, step, speed)
    top[top == -np.inf] = np.inf
    return top[m[:, 0].astype(np.intp)]


def figures(m: np.ndarray, dt: float, event: Optional[float]) -> dict[str, Optional[float]]:
    """FIGURES of one run from its metrics rows (world_sim.core.records.METRICS_COLUMNS, then under a channel
    hearing.LINK_COLUMNS, whose first is the usable graph's lambda2); None where a run that never converged, or
    has no event, has none."""
    t, rc, disc = m[:, 1], m[:, 2], joined(m)
    ok, connected = usable(m)
    out: dict[str, Optional[float]] = dict.fromkeys(FIGURES)
    out['ends_ok'] = float(ok[-int(round(HELD_S / dt)):].all())
    out['end_rc'], out['end_components'] = float(rc[-1]), float(m[-1, 5])
    if event is not None:
        after = np.flatnonzero(ok & (t >= event + dt / 2))
        out['recovery'] = float(t[after[0]] - event) if len(after) else None
    if ok.any():
        first = int(np.argmax(ok))
        whole = connected[first:]
        out.update(converged=float(t[first]), connected=float(whole.mean()),
                   splits=float(np.count_nonzero(whole[:-1] & ~whole[1:])),
                   outage=outage_s(~whole, dt), rc=float(rc[first:].mean()), disc=float(disc[first:].mean()))
    return out
