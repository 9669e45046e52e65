"""The world of one run, as the batch simulator and the world node share it: MSDs, MAP dynamics,
failures, what was sensed at a step, and the run's records (Mesa's model, without the agents)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from uav_agent.core.modes import NO_GOAL, ClusterMap

from . import physics
from .scenario import Scenario


@dataclass
class RunResult:
    scenario: Scenario
    users: physics.Users
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
        self.scenario = scenario
        rng = physics.streams(scenario.seed)
        self._fail_rng = rng['failure']
        self.users = physics.make_users(scenario, rng['users'])
        self.clusters = ClusterMap(self.users.centroids, scenario.flock.height, self.users.radii)
        self.q, self.p = physics.release(scenario, rng['release'])
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
        if self.fail_step is None or self.k != self.fail_step or self.scenario.fail_fraction <= 0:
            return np.zeros(0, np.intp)
        return physics.failure_ids(self.scenario, self.ids[self.alive], self._fail_rng)

    def drop(self, ids: np.ndarray) -> None:
        """MAPs that stopped flying: they leave the graph and serve no one from now on."""
        ids = np.asarray(ids, dtype=np.intp)
        self.alive[ids] = False
        self.failed = np.union1d(self.failed, ids).astype(np.intp)

    def sense(self) -> Sensed:
        """Associate and measure at q(k)."""
        fp = self.scenario.flock
        rows = self.ids[self.alive]
        q, p = self.q[rows], self.p[rows]
        assoc = physics.associate(self.users, q, fp.r, self.scenario.association)
        return Sensed(self.k, rows, q, p, physics.user_counts(assoc, len(rows)),
                      physics.cluster_coverage(self.users, assoc), physics.neighbour_pairs(q, fp.r),
                      physics.coverage_ratio(assoc), assoc=assoc)

    def advance(self, sensed: Sensed, u: np.ndarray, modes: np.ndarray, goals: np.ndarray,
                integrate: bool = True) -> np.ndarray:
        """Record step k with the MAPs' decisions and, unless told otherwise, integrate to k + 1.

        Returns the metrics row of step k.
        """
        rows = sensed.ids
        self.goal[rows] = goals
        n_comp = physics.components(sensed.pairs, len(rows))
        lam2 = physics.fiedler(sensed.pairs, len(rows), n_comp)
        counts = np.bincount(np.asarray(modes, dtype=np.intp), minlength=3)
        t = self.k * self.scenario.dt
        row = np.array([self.k, t, sensed.coverage_ratio, lam2, len(rows), n_comp, *counts[:3]], dtype=float)
        self._metrics.append(row)
        self._traj.append(np.column_stack([np.full(len(rows), self.k), np.full(len(rows), t), rows,
                                           sensed.q, sensed.p, modes, goals, sensed.n_users]))
        if integrate:
            self.q[rows], self.p[rows] = physics.integrate(sensed.q, sensed.p, u, self.scenario.dt)
            self.k += 1
        return row

    def result(self) -> RunResult:
        traj = np.concatenate(self._traj) if self._traj else np.zeros((0, 12))
        return RunResult(self.scenario, self.users, np.array(self._metrics).reshape(-1, 9), traj, self.failed,
                         self.fail_step if self.scenario.fail_fraction > 0 else None)
