"""The world of one run, as the batch simulator and the world node share it: MSDs, MAP dynamics,
failures, what was sensed at a step, and the run's records (Mesa's model, without the agents)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from uav_agent.core.clusters import NO_GOAL, ClusterMap
from uav_agent.core.safety import AWAY, HELD, RELAXED, RELEASED

from . import airframes, physics
from .records import Motion, metrics_columns
from .crowd import Crowd
from .hearing import LINK_COLUMNS, Hearing
from .scenario import Scenario
from .survey import NONE, Tracks, settle, survey


@dataclass
class RunResult:
    scenario: Scenario
    users: physics.Users
    metrics: np.ndarray                      # rows in records.METRICS_COLUMNS order
    trajectory: np.ndarray                   # rows in records.TRAJECTORY_COLUMNS order
    failed: np.ndarray = field(default_factory=lambda: np.zeros(0, np.intp))
    fail_step: Optional[int] = None
    motion: Optional[Motion] = None          # users that move: their positions at each survey step
    events: list[tuple[int, list[int], str]] = field(default_factory=list)  # (step, ids, cause) of each drop


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
    # Where the MAPs are (n, 3), when that is not where they believe they are (q: their GNSS estimate, what they
    # are told and tell); None: q is the truth. Association, coverage, range and the records take the truth.
    truth: Optional[np.ndarray] = None
    # A multirotor's traffic receiver (vehicle.traffic): ordered pairs (row, row) of the broadcasts each row receives.
    traffic: Optional[np.ndarray] = None

    def __post_init__(self) -> None:
        self.bounds = np.searchsorted(self.pairs[:, 0], np.arange(len(self.ids) + 1)).tolist()

    def neighbours(self, row: int) -> np.ndarray:
        """Rows of the neighbours of row, ascending."""
        return self.pairs[self.bounds[row]:self.bounds[row + 1], 1]

    def heard_traffic(self, row: int) -> np.ndarray:
        """Rows whose broadcasts row's traffic receiver took in, ascending (none without a receiver)."""
        if self.traffic is None:
            return np.zeros(0, dtype=np.intp)
        lo, hi = np.searchsorted(self.traffic[:, 0], [row, row + 1])
        return self.traffic[lo:hi, 1]


class World:
    """The physical world of one run: MSDs, MAP dynamics, failures and the run records."""

    def __init__(self, scenario: Scenario) -> None:
        self.scenario = scenario
        rng = physics.streams(scenario.seed)
        self._fail_rng = rng['failure']
        self.drawn = physics.make_users(scenario, rng['users'])  # the MSDs as drawn at t = 0
        self.users = self.drawn                                    # as they are at step k (present ones)
        self.clusters = ClusterMap(self.drawn.centroids, scenario.flock.height, self.drawn.radii)
        self.clusters_version = 0  # grows whenever the clusters the MAPs know change (Sensing says which)
        self.crowd = Crowd(scenario, self.drawn.xyz[:, :2], self.drawn.cluster, rng['walk']) \
            if scenario.users_move else None
        self.hearing = None if scenario.links.perfect else Hearing(scenario)  # what the MAPs hear, for the records
        self.tracks: Optional[Tracks] = None    # the last survey's clusters
        self.reported: Optional[Tracks] = None  # what the MAPs were told of them (survey.settle)
        self.label = self.drawn.cluster.copy()
        self.present = np.ones(len(self.label), dtype=bool)  # which drawn MSDs are there at the step placed
        self._placed = -1
        self._motion: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = []
        self.q, self.p = physics.release(scenario, rng['release'])
        self.flight = airframes.start(scenario.vehicle, scenario.maps, scenario.dt, rng['vehicle'])
        self.q, self.p = self.flight.release(self.q, self.p, scenario.release_center, scenario.release_half_width,
                                             rng['vehicle'])
        self.energy = 0.0  # J the formation has drawn so far (an airframe that is not exact: Airframe.power)
        # Rule 'release' as the MAPs' flags tell it (safety.AWAY, RELEASED): per MAP the steps it has been held back
        # from its goal without a break, the longest such run of any MAP, and the MAP-steps free of their links.
        self.away = np.zeros(scenario.maps, dtype=np.intp)
        self.away_longest = 0
        self.released = 0
        self.ids = np.arange(scenario.maps, dtype=np.intp)
        self.alive = np.ones(scenario.maps, dtype=bool)
        self.goal = np.full(scenario.maps, NO_GOAL, dtype=np.intp)  # each MAP's goal after its last step
        self.k = 0
        self.fail_step = None if scenario.fail_at is None else int(round(scenario.fail_at / scenario.dt))
        self.failed = np.zeros(0, np.intp)
        self.events: list[tuple[int, list[int], str]] = []  # (step, ids, 'scheduled' or 'killed'), as they came
        self._metrics: list[np.ndarray] = []
        self._traj: list[np.ndarray] = []
        self.place_users()  # the clusters the MAPs are given before the first step, as version 0

    def place_users(self) -> tuple[bool, bool]:
        """The MSDs at step k, surveyed when a survey is due: (clusters changed, users' positions due).

        Users that stand still under a given survey never change; an online survey of them runs once.
        """
        if self._placed == self.k:
            return False, False
        self._placed = self.k
        s = self.scenario
        if self.crowd is None and (s.survey == 'given' or self.k > 0):
            return False, False
        due = self.k % s.survey_steps == 0
        xy, present = self.crowd.at(self.k) if self.crowd else (self.drawn.xyz[:, :2], self.present)
        changed = False
        if s.survey == 'online' and due:
            tracks, labels = survey(xy[present], self.tracks, s.survey_steps * s.dt)
            self.label[:] = NONE
            self.label[present] = labels
            report = settle(self.reported, tracks)
            if self.reported is None or not report.same(self.reported):
                changed = self.reported is not None  # the first survey is what the MAPs start with
                # Roles carry their keys over from the survey before, as each MAP does (clusters.ClusterMap).
                carried = self.clusters if changed else None
                self.clusters = ClusterMap(report.centroids, s.flock.height, report.radii, report.active,
                                           report.velocities, previous=carried)
                self.clusters_version += int(changed)
            self.tracks, self.reported = tracks, report
        elif s.survey == 'given':
            self.label = np.where(present, self.drawn.cluster, NONE)
        self.present = present
        xyz = np.column_stack([xy[present], np.zeros(int(present.sum()))])
        self.users = physics.Users(xyz, self.label[present], self.clusters.xy, self.clusters.radii)
        moved = due and self.crowd is not None
        if moved:
            self._motion.append((self.k, xy.astype(np.float32), present.copy(), self.label.astype(np.int16)))
        return changed, moved

    def true_coverage(self, sensed: 'Sensed') -> np.ndarray:
        """Served fraction of each cluster as drawn (the scenario's clusters, whatever the survey found);
        NaN for one with no MSD present. What a benchmark judges arrivals by; sensed is the last step placed."""
        drawn = self.drawn.cluster[self.present]
        served = np.bincount(drawn[sensed.assoc != physics.UNSERVED], minlength=len(self.scenario.clusters))
        size = np.bincount(drawn, minlength=len(self.scenario.clusters))
        return np.where(size > 0, served / np.maximum(size, 1), np.nan)

    @property
    def failing_now(self) -> bool:
        """MAPs fail by the scenario's schedule at this step."""
        return self.fail_step is not None and self.k == self.fail_step and self.scenario.fail_fraction > 0

    def scheduled_failures(self) -> np.ndarray:
        """Ids that fail at this step by the scenario's schedule (empty on other steps)."""
        if not self.failing_now:
            return np.zeros(0, np.intp)
        return physics.failure_ids(self.scenario, self.ids[self.alive], self._fail_rng)

    def drop(self, ids: np.ndarray, cause: str = 'scheduled') -> None:
        """MAPs that stopped flying: they leave the graph and serve no one from now on."""
        ids = np.asarray(ids, dtype=np.intp)
        self.events.append((int(self.k), sorted(int(i) for i in ids), cause))
        self.alive[ids] = False
        self.failed = np.union1d(self.failed, ids).astype(np.intp)

    def sense(self) -> Sensed:
        """Associate and measure at q(k), with the MSDs where they are at step k."""
        self.place_users()
        fp = self.scenario.flock
        rows = self.ids[self.alive]
        q, p = self.q[rows], self.p[rows]
        assoc = physics.associate(self.users, q, fp.r, self.scenario.association)
        told = self.flight.estimate(rows, q)
        return Sensed(self.k, rows, told, p, physics.user_counts(assoc, len(rows)),
                      physics.cluster_coverage(self.users, assoc), physics.neighbour_pairs(q, fp.r),
                      physics.coverage_ratio(assoc), assoc=assoc, truth=None if self.flight.exact else q,
                      traffic=self.flight.traffic(q, told, p, fp))

    def advance(self, sensed: Sensed, u: np.ndarray, modes: np.ndarray, goals: np.ndarray,
                integrate: bool = True, flags: Optional[np.ndarray] = None) -> np.ndarray:
        """Record step k with the MAPs' decisions and, unless told otherwise, integrate to k + 1. flags: what each
        MAP's safety filter did to its command (safety.RELAXED, HELD, AWAY, RELEASED bits; None: nothing).

        Returns the metrics row of step k.
        """
        rows = sensed.ids
        self.goal[rows] = goals
        n_comp = physics.components(sensed.pairs, len(rows))
        lam2 = physics.fiedler(sensed.pairs, len(rows), n_comp)
        counts = np.bincount(np.asarray(modes, dtype=np.intp), minlength=3)
        t = self.k * self.scenario.dt
        row = np.array([self.k, t, sensed.coverage_ratio, lam2, len(rows), n_comp, *counts[:3]], dtype=float)
        if self.hearing is not None:  # under a channel: what the MAPs heard (hearing.LINK_COLUMNS)
            row = np.r_[row, self.hearing.row(self.k, rows, sensed.q, sensed.pairs)]
        q = sensed.q if sensed.truth is None else sensed.truth
        traj = [np.full(len(rows), self.k), np.full(len(rows), t), rows, q, sensed.p, modes, goals, sensed.n_users]
        if not self.flight.exact:  # a multirotor's (records.VEHICLE_COLUMNS, ESTIMATE_COLUMNS)
            watts = self.flight.power(rows, sensed.p)
            did = np.zeros(len(rows), dtype=np.uint8) if flags is None else np.asarray(flags, dtype=np.uint8)
            row = np.r_[row, physics.least_distance(q, sensed.pairs), watts.mean() if len(rows) else 0.0, self.energy,
                        np.count_nonzero(did & RELAXED), np.count_nonzero(did & HELD)]
            self.away[rows] = np.where(did & AWAY, self.away[rows] + 1, 0)
            self.away_longest = max(self.away_longest, int(self.away[rows].max(initial=0)))
            self.released += int(np.count_nonzero(did & RELEASED))
            self.energy += float(watts.sum()) * self.scenario.dt
            traj.append(sensed.q)
        self._metrics.append(row)
        self._traj.append(np.column_stack(traj))
        if integrate:
            self.q[rows], self.p[rows] = self.flight.step(rows, q, sensed.p, u)
            if self.crowd is not None:
                self.crowd.walk()
            self.k += 1
        return row

    def result(self) -> RunResult:
        columns = metrics_columns(self.scenario)
        width = 12 + (0 if self.flight.exact else 3)  # trajectory: TRAJECTORY_COLUMNS, ESTIMATE_COLUMNS
        traj = np.concatenate(self._traj) if self._traj else np.zeros((0, width))
        motion = None
        if self._motion:
            steps, xy, present, label = zip(*self._motion)
            motion = Motion(np.array(steps), np.stack(xy), np.stack(present), np.stack(label))
        return RunResult(self.scenario, self.drawn, np.array(self._metrics).reshape(-1, len(columns)), traj, self.failed,
                         self.fail_step if self.scenario.fail_fraction > 0 else None, motion, list(self.events))
