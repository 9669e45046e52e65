"""All MAPs in one process, stepping the very per-MAP functions the agent nodes run.

It is the oracle the distributed system must match: step k reads the world at q(k), lets every MAP
decide from its neighbours' states of step k (their achieved goals as of step k-1), then integrates.
The world half of that step is `core.model.World`, which the world node shares.
"""
from __future__ import annotations

from typing import Callable, Iterator, NamedTuple, Optional

import numpy as np

from uav_agent.core.agent import Neighbourhood, Said, after_filter, plan
from uav_agent.core.ear import Ear, Heard, Sent, hear
from uav_agent.core.control import Control, control_input
from uav_agent.core.policies import hearsay
from uav_agent.core.state import Memory, Reference

from world_sim.core.model import RunResult, Sensed, World
from world_sim.core.scenario import Scenario


class Decided(NamedTuple):
    """What every MAP decided at a step and why, kept for `uav-flock trace` (BatchSimulator(watch=True)): what it
    sensed, where its plan aimed it, each link it heard (owner row, the neighbour's state as heard, who keeps the
    link: state.UNKEPT, SHARED or ALONE) and its command with the nominal it came from."""

    sensed: Sensed
    refs: list[Reference]
    owner: np.ndarray
    nbr_q: np.ndarray
    needed: np.ndarray
    control: Control


class BatchSimulator:
    """A scenario stepped in-process; step() advances one Δt, run() to the end. watch: keep what each step
    decided (`decided`, a Decided) for a trace; the run flies the same either way."""

    def __init__(self, scenario: Scenario, watch: bool = False) -> None:
        self.scenario = scenario
        self.watch = watch
        self.decided: Optional[Decided] = None
        self.world = World(scenario)
        self.memory = [Memory() for _ in range(scenario.maps)]
        # What each MAP holds of its neighbours' states (ear.py).
        self.ears = [Ear(scenario.links, scenario.seed, i, hearsay(scenario.flock)) for i in range(scenario.maps)]
        self.held = [0] * scenario.maps  # each MAP's liveness count under the safety filter (agent.Step.held)

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
        hoods, owner, nbr = self.hear(sensed, said)
        refs, apart, needed = [], [], []
        for n, i in enumerate(rows.tolist()):
            self.memory[i], ref, kinds, keep = plan(self.memory[i], i, sensed.q[n], int(sensed.n_users[n]),
                                              sensed.cluster_coverage, hoods[n], w.clusters, fp, sensed.k, self.held[i])
            refs.append(ref)
            apart += kinds
            needed += keep
        target, qa, qb = (np.array([ref[c] for ref in refs]).reshape(-1, 3) for c in range(3))
        mode = np.array([ref.mode for ref in refs], dtype=np.intp)
        ref_vel = np.array([ref.velocity for ref in refs]).reshape(-1, 3, 3)
        seen = None if sensed.traffic is None else (sensed.traffic[:, 0], sensed.q[sensed.traffic[:, 1]],
                                                   sensed.p[sensed.traffic[:, 1]])
        control = control_input(sensed.q, sensed.p, sensed.n_users.astype(float), mode, target, qa, qb, owner, nbr.q,
                                nbr.p, nbr.n_users, fp, np.array(apart, dtype=np.intp), ref_vel, seen,
                                np.array(needed, dtype=np.int8), nbr.age)
        u, flags = control.u, control.flags
        if fp.safety == 'filter':  # the filter's liveness count, as each agent carries it (agent_step)
            flags = flags.copy()
            for n, i in enumerate(rows.tolist()):
                self.held[i], flags[n] = after_filter(self.held[i], int(flags[n]), sensed.q[n], refs[n], fp)
        if self.watch:
            self.decided = Decided(sensed, refs, owner, nbr.q, np.array(needed, dtype=np.int8),
                                   control._replace(flags=flags))
        modes = np.array([self.memory[i].mode for i in rows], dtype=np.intp)
        goals = np.array([self.memory[i].goal for i in rows], dtype=np.intp)
        w.advance(sensed, u, modes, goals, integrate, flags)
        return sensed

    def hear(self, sensed: Sensed, said: list[Said]) -> tuple[list[Neighbourhood], np.ndarray, Neighbourhood]:
        """Each MAP's neighbourhood at step k, as its agent node hears it (ear.hear: the states of step k of the
        neighbours within r, through the scenario's channel, with what each passed on); for eq. 9 over all MAPs
        at once, the owner row of each link and the neighbours' rows."""
        s, pairs, rows, bounds = self.scenario, sensed.pairs, sensed.ids, sensed.bounds
        passed = [self.ears[i].passed for i in rows.tolist()]  # what each message of step k passes on
        states = [Sent(int(rows[j]), Heard(sensed.q[j].copy(), sensed.p[j].copy(), float(sensed.n_users[j]), said[j]),
                       passed[j]) for j in range(len(rows))]
        near = pairs[:, 1].tolist()
        ears = [self.ears[i] for i in rows.tolist()]
        hear(ears, sensed.k, sensed.q, [[states[j] for j in near[bounds[n]:bounds[n + 1]]] for n in range(len(rows))], s.flock.r)
        hoods = [ear.neighbourhood(sensed.k, s.dt, sensed.q[n], s.flock.r) for n, ear in enumerate(ears)]
        owner = np.repeat(np.arange(len(rows), dtype=np.intp), [len(h.q) for h in hoods])
        return hoods, owner, Neighbourhood(
            np.concatenate([np.zeros((0, 3)), *(h.q for h in hoods)]), np.concatenate([np.zeros((0, 3)), *(h.p for h in hoods)]),
            np.concatenate([np.zeros(0), *(h.n_users for h in hoods)]), [], [],
            np.concatenate([np.zeros(0), *(h.age for h in hoods)]))

    def run(self, progress: Optional[Callable[[int], None]] = None) -> RunResult:
        """Steps 0..N (N = duration / dt), inclusive, so the record ends at t = duration."""
        for _ in self.flight(progress):
            pass
        return self.result()

    def flight(self, progress: Optional[Callable[[int], None]] = None) -> Iterator[BatchSimulator]:
        """The run a step at a time (what run() flies), itself after each step; the last is recorded without moving
        on. progress is called after each step that moved on."""
        for _ in range(self.scenario.steps):
            self.step()
            if progress:
                progress(1)
            yield self
        self.step(integrate=False)
        yield self

    def result(self) -> RunResult:
        return self.world.result()

