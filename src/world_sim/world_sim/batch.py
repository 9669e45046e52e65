"""All MAPs in one process, stepping the very per-MAP functions the agent nodes run.

It is the oracle the distributed system must match: step k reads the world at q(k), lets every MAP
decide from its neighbours' states of step k (their achieved goals as of step k-1), then integrates.
The world half of that step is `World`, which the world node shares.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from uav_agent.core.control import control_input
from uav_agent.core.modes import NO_GOAL, ClusterMap, Memory, Told, apart_links, decide, reference

from .core import world
from .core.scenario import Scenario


@dataclass
class RunResult:
    scenario: Scenario
    users: world.Users
    metrics: np.ndarray                      # rows in records.METRICS_COLUMNS order
    trajectory: np.ndarray                   # rows in records.TRAJECTORY_COLUMNS order
    failed: np.ndarray = field(default_factory=lambda: np.zeros(0, np.intp))
    fail_step: Optional[int] = None


@dataclass
class Sensed:
    """What the world measured at step k for its live MAPs (rows in ascending id)."""

    k: int
    ids: np.ndarray            # (n,) live MAP ids
    q: np.ndarray              # (n, 3)
    p: np.ndarray              # (n, 3)
    n_users: np.ndarray        # (n,) N_u
    cluster_coverage: np.ndarray  # (K,)
    pairs: np.ndarray          # (E, 2) ordered neighbour pairs (row, row), sorted; ids[row] is the MAP id
    coverage_ratio: float
    bounds: list[int] = field(default_factory=list)  # neighbours of row n are pairs[bounds[n]:bounds[n+1], 1]
    assoc: np.ndarray = field(default_factory=lambda: np.zeros(0, np.intp))  # (M,) row serving each MSD, or -1

    def __post_init__(self) -> None:
        self.bounds = np.searchsorted(self.pairs[:, 0], np.arange(len(self.ids) + 1)).tolist()

    def neighbours(self, row: int) -> np.ndarray:
        """Rows of the neighbours of row, ascending."""
        return self.pairs[self.bounds[row]:self.bounds[row + 1], 1]


class World:
    """The physical world of one run: MSDs, MAP dynamics, failures and the run records."""

    def __init__(self, scenario: Scenario) -> None:
        self.s = scenario
        rng = world.streams(scenario.seed)
        self._fail_rng = rng['failure']
        self.users = world.make_users(scenario, rng['users'])
        self.clusters = ClusterMap(self.users.centroids, scenario.flock.height, self.users.radii)
        self.q, self.p = world.release(scenario, rng['release'])
        self.ids = np.arange(scenario.maps, dtype=np.intp)
        self.alive = np.ones(scenario.maps, dtype=bool)
        self.goal = np.full(scenario.maps, NO_GOAL, dtype=np.intp)  # each MAP's goal after its last step
        self.k = 0
        self.fail_step = None if scenario.fail_at is None else int(round(scenario.fail_at / scenario.dt))
        self.failed = np.zeros(0, np.intp)
        self._metrics: list[np.ndarray] = []
        self._traj: list[np.ndarray] = []

    def scheduled_failures(self) -> np.ndarray:
        """Ids that fail at this step by the scenario's schedule (empty on other steps)."""
        if self.fail_step is None or self.k != self.fail_step or self.s.fail_fraction <= 0:
            return np.zeros(0, np.intp)
        return world.failure_ids(self.s, self.ids[self.alive], self._fail_rng)

    def drop(self, ids: np.ndarray) -> None:
        """MAPs that stopped flying: they leave the graph and serve no one from now on."""
        ids = np.asarray(ids, dtype=np.intp)
        self.alive[ids] = False
        self.failed = np.union1d(self.failed, ids).astype(np.intp)

    def sense(self) -> Sensed:
        """Associate and measure at q(k)."""
        fp = self.s.flock
        rows = self.ids[self.alive]
        q, p = self.q[rows], self.p[rows]
        assoc = world.associate(self.users, q, fp.r, self.s.association)
        return Sensed(self.k, rows, q, p, world.user_counts(assoc, len(rows)),
                      world.cluster_coverage(self.users, assoc), world.neighbour_pairs(q, fp.r),
                      world.coverage_ratio(assoc), assoc=assoc)

    def advance(self, sensed: Sensed, u: np.ndarray, modes: np.ndarray, goals: np.ndarray,
                integrate: bool = True) -> np.ndarray:
        """Record step k with the MAPs' decisions and, unless told otherwise, integrate to k + 1.

        Returns the metrics row of step k.
        """
        rows = sensed.ids
        self.goal[rows] = goals
        n_comp = world.components(sensed.pairs, len(rows))
        lam2 = world.fiedler(sensed.pairs, len(rows), n_comp)
        counts = np.bincount(np.asarray(modes, dtype=np.intp), minlength=3)
        t = self.k * self.s.dt
        row = np.array([self.k, t, sensed.coverage_ratio, lam2, len(rows), n_comp, *counts[:3]], dtype=float)
        self._metrics.append(row)
        self._traj.append(np.column_stack([np.full(len(rows), self.k), np.full(len(rows), t), rows,
                                           sensed.q, sensed.p, modes, goals, sensed.n_users]))
        if integrate:
            self.q[rows], self.p[rows] = world.integrate(sensed.q, sensed.p, u, self.s.dt)
            self.k += 1
        return row

    def result(self) -> RunResult:
        traj = np.concatenate(self._traj) if self._traj else np.zeros((0, 12))
        return RunResult(self.s, self.users, np.array(self._metrics).reshape(-1, 9), traj, self.failed,
                         self.fail_step)


class BatchSimulator:
    """A scenario stepped in-process; step() advances one Δt, run() to the end."""

    def __init__(self, scenario: Scenario) -> None:
        self.s = scenario
        self.world = World(scenario)
        self.memory = [Memory() for _ in range(scenario.maps)]

    # Views kept for callers that inspect the run as it goes.
    users = property(lambda self: self.world.users)
    clusters = property(lambda self: self.world.clusters)
    q = property(lambda self: self.world.q)
    p = property(lambda self: self.world.p)
    ids = property(lambda self: self.world.ids)
    alive = property(lambda self: self.world.alive)

    def step(self, integrate: bool = True) -> None:
        """Record step k and, unless told otherwise, advance to k + 1."""
        w, fp = self.world, self.s.flock
        failing = w.scheduled_failures()
        if len(failing):
            w.drop(failing)
        sensed = w.sense()
        rows = sensed.ids
        stated = [self.memory[i] for i in rows]  # what each MAP's state message of step k carries
        told = [m.achieved for m in stated]
        roles = [Told(m.mode, m.goal, m.bridge) for m in stated]
        nbr, counts, bounds = sensed.pairs[:, 1].tolist(), sensed.n_users.tolist(), sensed.bounds
        refs, apart = [], []
        for n, i in enumerate(rows.tolist()):
            near = nbr[bounds[n]:bounds[n + 1]]
            heard = [told[j] for j in near]
            mem = decide(self.memory[i], i, counts[n], sensed.cluster_coverage, sensed.q[n], heard, w.clusters, fp)
            self.memory[i] = mem
            heard_roles = [roles[j] for j in near]
            refs.append(reference(mem, i, sensed.q[n], sensed.q[near], heard_roles, w.clusters, fp))
            apart += apart_links(mem, heard_roles, fp)
        target, qa, qb = (np.array([ref[c] for ref in refs]).reshape(-1, 3) for c in range(3))
        mode = np.array([ref[3] for ref in refs], dtype=np.intp)
        pairs = sensed.pairs
        u = control_input(sensed.q, sensed.p, sensed.n_users.astype(float), mode, target, qa, qb, pairs[:, 0],
                          sensed.q[pairs[:, 1]], sensed.p[pairs[:, 1]], sensed.n_users[pairs[:, 1]].astype(float), fp,
                          np.array(apart, dtype=bool))
        modes = np.array([self.memory[i].mode for i in rows], dtype=np.intp)
        goals = np.array([self.memory[i].goal for i in rows], dtype=np.intp)
        w.advance(sensed, u, modes, goals, integrate)

    def run(self, progress: Optional[Callable[[int], None]] = None) -> RunResult:
        """Steps 0..N (N = duration / dt), inclusive, so the record ends at t = duration."""
        for _ in range(self.s.steps):
            self.step()
            if progress:
                progress(1)
        self.step(integrate=False)
        return self.result()

    def result(self) -> RunResult:
        return self.world.result()
