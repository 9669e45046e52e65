"""All MAPs in one process, stepping the very per-MAP functions the agent nodes run.

It is the oracle the distributed system must match: step k reads the world at q(k), lets every MAP
decide from its neighbours' states of step k (their achieved goals as of step k-1), then integrates.
The world half of that step is `core.model.World`, which the world node shares.
"""
from __future__ import annotations

from typing import Callable, Optional

import numpy as np

from uav_agent.core.agent import Neighbourhood, Said, plan
from uav_agent.core.control import control_input
from uav_agent.core.state import Memory

from world_sim.core.model import RunResult, Sensed, World
from world_sim.core.scenario import Scenario


class BatchSimulator:
    """A scenario stepped in-process; step() advances one Δt, run() to the end."""

    def __init__(self, scenario: Scenario) -> None:
        self.scenario = scenario
        self.world = World(scenario)
        self.memory = [Memory() for _ in range(scenario.maps)]

    # Views kept for callers that inspect the run as it goes.
    users = property(lambda self: self.world.users)
    clusters = property(lambda self: self.world.clusters)
    q = property(lambda self: self.world.q)
    p = property(lambda self: self.world.p)
    ids = property(lambda self: self.world.ids)
    alive = property(lambda self: self.world.alive)

    def step(self, integrate: bool = True) -> Sensed:
        """Record step k and, unless told otherwise, advance to k + 1; returns what was sensed at step k."""
        w, fp = self.world, self.scenario.flock
        failing = w.scheduled_failures()
        if len(failing):
            w.drop(failing)
        sensed = w.sense()
        rows = sensed.ids
        said = [Said.of(self.memory[i]) for i in rows]  # what each MAP's state message of step k carries
        nbr, counts, bounds = sensed.pairs[:, 1].tolist(), sensed.n_users.tolist(), sensed.bounds
        refs, apart = [], []
        for n, i in enumerate(rows.tolist()):
            near = nbr[bounds[n]:bounds[n + 1]]
            hood = Neighbourhood.hearing(sensed.q[near], sensed.p[near], sensed.n_users[near],
                                         [said[j] for j in near])
            self.memory[i], ref, links = plan(self.memory[i], i, sensed.q[n], counts[n], sensed.cluster_coverage,
                                              hood, w.clusters, fp, sensed.k)
            refs.append(ref)
            apart += links
        target, qa, qb = (np.array([ref[c] for ref in refs]).reshape(-1, 3) for c in range(3))
        mode = np.array([ref.mode for ref in refs], dtype=np.intp)
        ref_vel = np.array([ref.velocity for ref in refs]).reshape(-1, 3, 3)
        pairs = sensed.pairs
        u = control_input(sensed.q, sensed.p, sensed.n_users.astype(float), mode, target, qa, qb, pairs[:, 0],
                          sensed.q[pairs[:, 1]], sensed.p[pairs[:, 1]], sensed.n_users[pairs[:, 1]].astype(float), fp,
                          np.array(apart, dtype=np.intp), ref_vel)
        modes = np.array([self.memory[i].mode for i in rows], dtype=np.intp)
        goals = np.array([self.memory[i].goal for i in rows], dtype=np.intp)
        w.advance(sensed, u, modes, goals, integrate)
        return sensed

    def run(self, progress: Optional[Callable[[int], None]] = None) -> RunResult:
        """Steps 0..N (N = duration / dt), inclusive, so the record ends at t = duration."""
        for _ in range(self.scenario.steps):
            self.step()
            if progress:
                progress(1)
        self.step(integrate=False)
        return self.result()

    def result(self) -> RunResult:
        return self.world.result()
