"""The batch simulator is the oracle: a MAP's own agent_step, fed what its node would receive, must move it
exactly where the batch simulator moved it."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from uav_agent.agent_node import said
from uav_agent.core import policies
from uav_agent.core.agent import Neighbourhood, agent_step
from uav_agent.core.clusters import ids_of
from uav_agent.core.params import FlockParams
from uav_agent.core.state import Told
from uav_flock_ros import convert
from uav_flock_tools.batch import BatchSimulator
from world_sim.core import layouts, physics
from world_sim.core.scenario import load


@pytest.mark.parametrize('allocation', list(policies.ALLOCATIONS))  # every registered one
def test_agent_step_reproduces_the_batch_step_bit_for_bit(paper_scenario_path: str, allocation: str) -> None:
    s = load(paper_scenario_path).with_overrides(maps=30, seed=3, duration=12.0)
    if allocation != s.flock.allocation:  # any other than the paper's: on a random layout, default open choices
        s = replace(layouts.draw(s, layouts.LayoutSpec(), np.random.default_rng(7)), flock=replace(
            s.flock, allocation=allocation, edge_choice=FlockParams().edge_choice))
    assert s.flock.allocation == allocation
    sim = BatchSimulator(s)
    checked = 0
    for k in range(s.steps):
        if k % 20 == 0:  # compare at several phases: flight, arrival, mode switches
            rows = sim.ids[sim.alive]
            q, p, memory = sim.q[rows].copy(), sim.p[rows].copy(), list(sim.memory)
            assoc = physics.associate(sim.users, q, s.flock.r, s.association)
            n_u = physics.user_counts(assoc, len(rows))
            cover = physics.cluster_coverage(sim.users, assoc)
            pairs = physics.neighbour_pairs(q, s.flock.r)
            sim.step()
            for n, i in enumerate(rows):
                nbr = pairs[pairs[:, 0] == n, 1]
                # what each neighbour's state message says, as the node converts it from the wire
                heard = [convert.AgentStateData(int(j), k, q[j], p[j], int(n_u[j]), memory[j].mode, memory[j].goal,
                                                memory[j].bridge, tuple(ids_of(memory[j].achieved)),
                                                Told.of(memory[j]).block) for j in nbr]
                hood = Neighbourhood.hearing(q[nbr], p[nbr], n_u[nbr], [said(m) for m in heard])
                u, mem, *_ = agent_step(memory[i], int(i), q[n], p[n], int(n_u[n]), cover, hood, sim.clusters, s.flock, k)
                q_next, p_next = physics.integrate(q[n][None], p[n][None], u[None], s.dt)
                assert mem == sim.memory[i], f'MAP {i} decided differently at step {k}'
                assert np.array_equal(q_next[0], sim.q[i]) and np.array_equal(p_next[0], sim.p[i]), \
                    f'MAP {i} moved differently at step {k}: {q_next[0] - sim.q[i]}'
                checked += 1
        else:
            sim.step()
    assert checked == 30 * len(range(0, s.steps, 20))
    modes = {m.mode for m in sim.memory}
    assert len(modes) > 1, 'the check should cover more than one mode'
