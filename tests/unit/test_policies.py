"""The allocation registry (core/policies.py): a new allocation is a class and one line."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from uav_agent.core import policies, state
from uav_agent.core.clusters import ClusterMap
from uav_agent.core.params import FlockParams
from uav_agent.core.state import M0, M2, Memory, Told
from uav_flock_tools.batch import BatchSimulator
from world_sim.core.scenario import load


class Nearest:
    """The allocation of docs/design.md's example: serve the nearest cluster, attract only its other servers."""

    def decide(self, mem: Memory, agent_id: int, n_users: int, r_g: float, q: np.ndarray, clusters: ClusterMap,
               fp: FlockParams, step: int, near: 'state.Near') -> Memory:
        from uav_agent.core.clusters import NO_GOAL
        goal = clusters.nearest(q, 0)
        return mem._replace(goal=goal, mode=M2 if goal != NO_GOAL and r_g > fp.r0 else M0)

    def reference(self, mem: Memory, agent_id: int, q: np.ndarray, nbr_q: np.ndarray, told: list[Told],
                  clusters: ClusterMap, fp: FlockParams) -> 'state.Reference':
        return state.hold(mem, *state.aim(mem, q, clusters))

    def link(self, a: Told, b: Told) -> int:
        return state.RELATED if a.goal == b.goal else state.APART


def test_a_new_allocation_is_a_class_and_one_registry_line(paper_scenario_path: str,
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(policies.ALLOCATIONS, 'nearest', Nearest())
    s = load(paper_scenario_path).with_overrides(maps=30, duration=20.0)
    s = replace(s, flock=replace(s.flock, allocation='nearest'))
    sim = BatchSimulator(s)
    result = sim.run()
    assert set(result.trajectory[:, 9].astype(int).tolist()) <= {M0, M2}, 'it never bridges'
    assert all(m.goal == sim.clusters.nearest(q, 0) for m, q in zip(sim.memory, sim.q)), \
        'every MAP ends serving its nearest cluster'
