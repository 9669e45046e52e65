"""All MAPs in one process, stepping the very per-MAP functions the agent nodes run.

It is the oracle the distributed system must match: step k reads the world at q(k), lets every MAP
decide from its neighbours' states of step k (their achieved goals as of step k-1), then integrates.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from uav_agent.core.control import control_input
from uav_agent.core.modes import ClusterMap, Memory, decide, reference

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


class BatchSimulator:
    """A scenario stepped in-process; step() advances one Δt, run() to the end."""

    def __init__(self, scenario: Scenario) -> None:
        self.s = scenario
        rng = world.streams(scenario.seed)
        self._fail_rng = rng['failure']
        self.users = world.make_users(scenario, rng['users'])
        self.clusters = ClusterMap(self.users.centroids, scenario.flock.height)
        self.q, self.p = world.release(scenario, rng['release'])
        self.ids = np.arange(scenario.maps, dtype=np.intp)
        self.alive = np.ones(scenario.maps, dtype=bool)
        self.memory = [Memory() for _ in range(scenario.maps)]
        self.k = 0
        self.fail_step = None if scenario.fail_at is None else int(round(scenario.fail_at / scenario.dt))
        self.failed = np.zeros(0, np.intp)
        self._metrics: list[np.ndarray] = []
        self._traj: list[np.ndarray] = []

    def _apply_failures(self) -> None:
        if self.fail_step is not None and self.k == self.fail_step and self.s.fail_fraction > 0:
            self.failed = world.failure_ids(self.s, self.ids[self.alive], self._fail_rng)
            self.alive[self.failed] = False

    def step(self, integrate: bool = True) -> None:
        """Record step k and, unless told otherwise, advance to k + 1."""
        s, fp = self.s, self.s.flock
        self._apply_failures()
        rows = self.ids[self.alive]
        q, p = self.q[rows], self.p[rows]
        assoc = world.associate(self.users, q, fp.r, s.association)
        n_u = world.user_counts(assoc, len(rows))
        cover = world.cluster_coverage(self.users, assoc)
        pairs = world.neighbour_pairs(q, fp.r)
        starts = np.searchsorted(pairs[:, 0], np.arange(len(rows) + 1))
        told = [self.memory[i].achieved for i in rows]  # what each MAP's state message of step k carries
        nbr, bounds, counts = pairs[:, 1].tolist(), starts.tolist(), n_u.tolist()
        refs = []
        for n, i in enumerate(rows.tolist()):
            heard = [told[j] for j in nbr[bounds[n]:bounds[n + 1]]]
            mem = decide(self.memory[i], i, counts[n], cover, q[n], heard, self.clusters, fp)
            self.memory[i] = mem
            refs.append(reference(mem, self.clusters))
        target, qa, qb = (np.array([ref[c] for ref in refs]).reshape(-1, 3) for c in range(3))
        mode = np.array([ref[3] for ref in refs], dtype=np.intp)
        u = control_input(q, p, n_u.astype(float), mode, target, qa, qb, pairs[:, 0],
                          q[pairs[:, 1]], p[pairs[:, 1]], n_u[pairs[:, 1]].astype(float), fp)
        self._record(rows, q, p, n_u, pairs, world.coverage_ratio(assoc))
        if integrate:
            self.q[rows], self.p[rows] = world.integrate(q, p, u, s.dt)
            self.k += 1

    def _record(self, rows: np.ndarray, q: np.ndarray, p: np.ndarray, n_u: np.ndarray,
                pairs: np.ndarray, r_c: float) -> None:
        t = self.k * self.s.dt
        modes = np.array([self.memory[i].mode for i in rows], dtype=np.intp)
        goals = np.array([self.memory[i].goal for i in rows], dtype=np.intp)
        n_comp = world.components(pairs, len(rows))
        lam2 = world.fiedler(pairs, len(rows), n_comp)
        counts = np.bincount(modes, minlength=3)
        self._metrics.append(np.array([self.k, t, r_c, lam2, len(rows), n_comp, *counts[:3]], dtype=float))
        block = np.column_stack([np.full(len(rows), self.k), np.full(len(rows), t), rows, q, p, modes, goals, n_u])
        self._traj.append(block)

    def run(self, progress: Optional[Callable[[int], None]] = None) -> RunResult:
        """Steps 0..N (N = duration / dt), inclusive, so the record ends at t = duration."""
        for _ in range(self.s.steps):
            self.step()
            if progress:
                progress(1)
        self.step(integrate=False)
        return self.result()

    def result(self) -> RunResult:
        return RunResult(self.s, self.users, np.array(self._metrics), np.concatenate(self._traj),
                         self.failed, self.fail_step)
