"""Algorithm 2 case by case, the cluster MST, bridge choice and gossip."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from uav_agent.core.allocations.algorithm2 import choose_bridge, mode_switch
from uav_agent.core.clusters import NO_GOAL, ClusterMap, ids_of, mask_of, merge_achieved
from uav_agent.core.policies import decide
from uav_agent.core.state import M0, M1, M2, Memory
from uav_agent.core.params import FlockParams

P = FlockParams(allocation="algorithm2")  # the paper's Algorithm 2 with its shipped policies
# Four clusters on a line-ish layout: 0 (0,0), 1 (100,0), 2 (100,100), 3 (300,0).
CLUSTERS = ClusterMap(np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 100.0], [300.0, 0.0]]), height=20.0)
HERE = np.array([5.0, 0.0, 20.0])


def at_goal_0(mode: int = M0, achieved: int = 0) -> Memory:
    return Memory(mode=mode, goal=0, achieved=achieved)


@pytest.mark.parametrize('mode', [M0, M1, M2])
def test_goal_not_yet_covered_changes_nothing(mode: int) -> None:
    mem = at_goal_0(mode)
    assert mode_switch(mem, 5, P.r0, HERE, CLUSTERS, P) == mem  # r_g must exceed r0 strictly


def test_few_users_move_on_to_the_nearest_uncovered_cluster() -> None:
    out = mode_switch(at_goal_0(), 2, 0.99, HERE, CLUSTERS, P)
    assert (out.mode, out.goal, ids_of(out.achieved)) == (M0, 1, [0])


def test_some_users_switch_to_connectivity() -> None:
    for n in (P.n0, P.n1 - 1):
        assert mode_switch(at_goal_0(), n, 0.99, HERE, CLUSTERS, P).mode == M1


def test_many_users_switch_to_static() -> None:
    for n in (P.n1, 500):
        out = mode_switch(at_goal_0(), n, 0.99, HERE, CLUSTERS, P)
        assert (out.mode, out.goal) == (M2, 0)


def test_no_users_follows_the_policy() -> None:
    assert mode_switch(at_goal_0(), 0, 0.99, HERE, CLUSTERS, P).goal == 1
    literal = dataclasses.replace(P, zero_users='static')
    assert mode_switch(at_goal_0(), 0, 0.99, HERE, CLUSTERS, literal).mode == M2


@pytest.mark.parametrize('mode', [M1, M2])
def test_connectivity_and_static_modes_are_kept_but_record_the_goal(mode: int) -> None:
    out = mode_switch(at_goal_0(mode), 2, 0.99, HERE, CLUSTERS, P)
    assert out.mode == mode and out.achieved == mask_of([0])


def test_first_step_picks_the_nearest_cluster() -> None:
    assert mode_switch(Memory(), 0, 0.0, np.array([290.0, 5.0, 20.0]), CLUSTERS, P).goal == 3


def test_exhausted_dynamic_map_bridges_or_serves() -> None:
    everything = mask_of(range(4))
    mem = Memory(mode=M0, goal=3, achieved=everything)
    assert mode_switch(mem, 1, 0.99, HERE, CLUSTERS, P).mode == M1
    serve = dataclasses.replace(P, m0_exhausted='serve')
    out = mode_switch(mem, 1, 0.99, HERE, CLUSTERS, serve)
    assert (out.mode, out.goal) == (M0, 3)


def test_mst_over_achieved_clusters() -> None:
    assert CLUSTERS.mst(mask_of([0])) == ()
    assert CLUSTERS.mst(mask_of([0, 1, 2, 3])) == ((0, 1), (1, 2), (1, 3))
    assert CLUSTERS.mst(mask_of([0, 2, 3])) == ((0, 2), (2, 3))  # 141 + 224 beats 300


def test_gossip_is_a_union() -> None:
    assert merge_achieved(mask_of([0]), [mask_of([2]), mask_of([2, 3])]) == mask_of([0, 2, 3])


def test_nearest_edge_and_keeping_it() -> None:
    mem = Memory(mode=M1, goal=0, achieved=mask_of(range(4)))
    near = dataclasses.replace(P, edge_choice='nearest')
    assert choose_bridge(mem, 7, np.array([100.0, 60.0, 20.0]), CLUSTERS, near).bridge == (1, 2)
    keep = dataclasses.replace(P, edge_choice='keep_nearest')
    kept = mem._replace(bridge=(1, 3))
    assert choose_bridge(kept, 7, np.array([100.0, 60.0, 20.0]), CLUSTERS, keep).bridge == (1, 3)


def test_shared_edges_split_maps_in_proportion_to_edge_length() -> None:
    edges = CLUSTERS.mst(mask_of(range(4)))  # lengths 100, 100, 200
    picks = [CLUSTERS.shared_edge(i, edges) for i in range(400)]
    share = {e: picks.count(e) / len(picks) for e in edges}
    assert share[(0, 1)] == pytest.approx(0.25, abs=0.02)
    assert share[(1, 2)] == pytest.approx(0.25, abs=0.02)
    assert share[(1, 3)] == pytest.approx(0.5, abs=0.02)


def test_connectivity_mode_without_an_edge_holds_at_its_goal() -> None:
    mem = decide(Memory(mode=M1, goal=0, achieved=mask_of([0])), 3, 5, np.zeros(4), HERE, [], CLUSTERS, P)
    assert mem.bridge is None and mem.goal == 0
    assert NO_GOAL == -1
