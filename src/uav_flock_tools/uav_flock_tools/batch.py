"""All MAPs in one process, stepping the very per-MAP functions the agent nodes run.

It is the oracle the distributed system must match: step k reads the world at q(k), lets every MAP
decide from its neighbours' states of step k (their achieved goals as of step k-1), then integrates.
The world half of that step is `core.model.World`, which the world node shares.
"""
from __future__ import annotations

from typing import Callable, Optional

import numpy as np

from uav_agent.core import links
from uav_agent.core.agent import Heard, Hearing, Neighbourhood, Said, plan
from uav_agent.core.control import control_input
from uav_agent.core.policies import hearsay
from uav_agent.core.state import Memory

from world_sim.core.model import RunResult, Sensed, World
from world_sim.core.scenario import Scenario


class BatchSimulator:
    """A scenario stepped in-process; step() advances one Δt, run() to the end."""

    def __init__(self, scenario: Scenario) -> None:
        self.scenario = scenario
        self.world = World(scenario)
        self.memory = [Memory() for _ in range(scenario.maps)]
        # What each MAP holds of its neighbours' states, under a channel that is not the paper's (links.py).
        self.inboxes: Optional[list[Hearing]] = \
            None if scenario.links.perfect else [Hearing(scenario.links, i, hearsay(scenario.flock)) for i in range(scenario.maps)]

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
        hoods, owner, nbr = self.hear(sensed, said) if self.inboxes is not None else self.hear_all(sensed, said)
        refs, apart = [], []
        for n, i in enumerate(rows.tolist()):
            self.memory[i], ref, kinds = plan(self.memory[i], i, sensed.q[n], int(sensed.n_users[n]),
                                              sensed.cluster_coverage, hoods[n], w.clusters, fp, sensed.k)
            refs.append(ref)
            apart += kinds
        target, qa, qb = (np.array([ref[c] for ref in refs]).reshape(-1, 3) for c in range(3))
        mode = np.array([ref.mode for ref in refs], dtype=np.intp)
        ref_vel = np.array([ref.velocity for ref in refs]).reshape(-1, 3, 3)
        seen = None if sensed.traffic is None else (sensed.traffic[:, 0], sensed.q[sensed.traffic[:, 1]],
                                                   sensed.p[sensed.traffic[:, 1]])
        u = control_input(sensed.q, sensed.p, sensed.n_users.astype(float), mode, target, qa, qb, owner, nbr.q,
                          nbr.p, nbr.n_users, fp, np.array(apart, dtype=np.intp), ref_vel, seen)
        modes = np.array([self.memory[i].mode for i in rows], dtype=np.intp)
        goals = np.array([self.memory[i].goal for i in rows], dtype=np.intp)
        w.advance(sensed, u, modes, goals, integrate)
        return sensed

    def hear_all(self, sensed: Sensed, said: list[Said]) -> tuple[list[Neighbourhood], np.ndarray, Neighbourhood]:
        """The paper's channel: each MAP hears every neighbour within r at once. Per MAP its neighbourhood;
        for eq. 9 over all MAPs at once, the owner row of each link and the neighbours' rows."""
        pairs, bounds = sensed.pairs, sensed.bounds
        near = pairs[:, 1].tolist()
        hoods = [Neighbourhood.hearing(sensed.q[js], sensed.p[js], sensed.n_users[js], [said[j] for j in js])
                 for js in (near[bounds[n]:bounds[n + 1]] for n in range(len(sensed.ids)))]
        return hoods, pairs[:, 0], Neighbourhood(sensed.q[pairs[:, 1]], sensed.p[pairs[:, 1]],
                                                 sensed.n_users[pairs[:, 1]].astype(float), [], [])

    def hear(self, sensed: Sensed, said: list[Said]) -> tuple[list[Neighbourhood], np.ndarray, Neighbourhood]:
        """hear_all through the scenario's channel: each MAP decides which neighbour states of step k it hears
        (links.heard, as its agent node does), with the states each heard one passes on (Hearing.hear), and
        uses the latest one of each neighbour it may use now (links.Inbox)."""
        assert self.inboxes is not None
        s, pairs, rows = self.scenario, sensed.pairs, sensed.ids
        ok = links.heard(s.links, s.seed, sensed.k, rows[pairs[:, 0]], rows[pairs[:, 1]], sensed.q[pairs[:, 0]],
                         sensed.q[pairs[:, 1]], s.flock.r)
        hoods, owner = [], []
        passed = [self.inboxes[i].passed for i in rows.tolist()]  # what each message of step k passes on
        for n, i in enumerate(rows.tolist()):
            js = pairs[sensed.bounds[n]:sensed.bounds[n + 1], 1][ok[sensed.bounds[n]:sensed.bounds[n + 1]]]
            self.inboxes[i].hear(sensed.k, rows[js].tolist(), [Heard(sensed.q[j].copy(), sensed.p[j].copy(),
                                                                     float(sensed.n_users[j]), said[j]) for j in js],
                                 [passed[j] for j in js])
            hoods.append(self.inboxes[i].neighbourhood(sensed.k, s.dt, sensed.q[n], s.flock.r))
            owner += [n] * len(hoods[-1].q)
        return hoods, np.array(owner, dtype=np.intp), Neighbourhood(
            np.concatenate([np.zeros((0, 3)), *(h.q for h in hoods)]), np.concatenate([np.zeros((0, 3)), *(h.p for h in hoods)]),
            np.concatenate([np.zeros(0), *(h.n_users for h in hoods)]), [], [])

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

