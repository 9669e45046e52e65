"""The paper's Algorithm 2 (`allocation: algorithm2`): a MAP flies to the nearest uncovered cluster and, by
how many users it serves there, moves on (M0), bridges an edge of the MST over the achieved clusters (M1)
or stays (M2). The cases the paper leaves open are settled by the policies of FlockParams
(docs/choices.md)."""
from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

import numpy as np

from ..clusters import NO_GOAL, ClusterMap
from ..state import M0, M1, M2, NOBODY, RELATED, UNKEPT, Memory, Near, Reference, Told, aim, hold

if TYPE_CHECKING:
    from ..params import FlockParams


def mode_switch(mem: Memory, n_users: int, goal_coverage: float, q: np.ndarray,
                clusters: ClusterMap, fp: FlockParams) -> Memory:
    """Algorithm 2 for one MAP at one step, with the paper's open cases resolved by the policies in fp.

    goal_coverage is r_g^i, the served fraction of the current goal cluster. A MAP whose goal cluster
    has left (an online survey ended it) starts over in M0 towards the nearest uncovered cluster.
    """
    if mem.goal != NO_GOAL and not clusters.live >> mem.goal & 1:
        mem = mem._replace(mode=M0, goal=NO_GOAL, bridge=None)
    if mem.goal == NO_GOAL:  # first step: the nearest uncovered cluster (any cluster if all are covered)
        nxt = clusters.nearest(q, mem.achieved)
        return mem._replace(goal=nxt if nxt != NO_GOAL else clusters.nearest(q, 0))
    if not goal_coverage > fp.r0:
        return mem
    if not mem.achieved >> mem.goal & 1:
        mem = mem._replace(achieved=mem.achieved | 1 << mem.goal)
    if mem.mode != M0:
        return mem
    if 0 < n_users < fp.n0 or (n_users == 0 and fp.zero_users == 'move_on'):
        nxt = clusters.nearest(q, mem.achieved)
        if nxt != NO_GOAL:
            return mem._replace(goal=nxt)
        if fp.m0_exhausted == 'bridge' and len(clusters.mst(mem.achieved)) > 0:
            return mem._replace(mode=M1)
        return mem
    if fp.n0 <= n_users < fp.n1:
        return mem._replace(mode=M1)
    return mem._replace(mode=M2)


def choose_bridge(mem: Memory, agent_id: int, q: np.ndarray, clusters: ClusterMap, fp: FlockParams) -> Memory:
    """Which MST edge an M1 MAP bridges, by fp.edge_choice: the nearest (re-chosen each step or kept
    while in the tree), or its share of the tree by edge length."""
    if mem.mode != M1:
        return mem if mem.bridge is None else mem._replace(bridge=None)
    edges = clusters.mst(mem.achieved)
    if not edges:
        if fp.m1_pending == 'lead' and mem.goal != NO_GOAL:
            ahead = clusters.nearest(q, mem.achieved)
            if ahead != NO_GOAL:
                return mem._replace(bridge=(mem.goal, ahead))
        return mem._replace(bridge=None) if mem.bridge is not None else mem
    if fp.edge_choice == 'share':
        edge = clusters.shared_edge(agent_id, edges)
    elif fp.edge_choice == 'keep_nearest' and mem.bridge in edges:
        return mem
    else:
        edge = clusters.nearest_edge(q, edges)
    return mem if edge == mem.bridge else mem._replace(bridge=edge)


class Algorithm2:
    """Algorithm 2 as an allocation (policies.Allocation)."""

    # Every neighbour attracts in its lattice: with states passed on, the paper layout split for good in one
    # seed of eight under either channel (docs/links.md, "Hearsay").
    hearsay = False

    def decide(self, mem: Memory, agent_id: int, n_users: int, r_g: float, q: np.ndarray, clusters: ClusterMap,
               fp: FlockParams, step: int = 0, near: Near = NOBODY) -> Memory:
        mem = mode_switch(mem, n_users, r_g, q, clusters, fp)
        return choose_bridge(mem, agent_id, q, clusters, fp)

    def reference(self, mem: Memory, agent_id: int, q: np.ndarray, nbr_q: np.ndarray, told: Sequence[Told],
                  clusters: ClusterMap, fp: FlockParams) -> Reference:
        """An M1 MAP is drawn to the segment between its bridge's two centres (eq. 13)."""
        here, v = aim(mem, q, clusters)
        if mem.mode == M1 and mem.bridge is not None:
            va, vb = clusters.velocities[mem.bridge[0]], clusters.velocities[mem.bridge[1]]
            return Reference(here, clusters.targets[mem.bridge[0]], clusters.targets[mem.bridge[1]], M1,
                             np.array([v, va, vb]))
        return hold(mem, here, v)

    def link(self, a: Told, b: Told, fp: FlockParams) -> int:
        """Every neighbour alike: the paper's flocking terms take them all."""
        return RELATED

    def needed(self, own: Memory, other: Told) -> int:
        """None: Algorithm 2 names no chains, so the safety filter keeps no link under it."""
        return UNKEPT
