"""Algorithm 2 (mode switch), the MST over achieved clusters and the gossip of achieved goals.

Achieved-goal sets travel as bit masks (bit k = cluster k achieved): gossip is then a bitwise OR, the
"merge by union" of the paper's shared list of achieved goals.
"""
from __future__ import annotations

from functools import lru_cache
from typing import Iterable, NamedTuple, Optional

import numpy as np
from scipy.sparse.csgraph import minimum_spanning_tree

from .control import M0, M1, M2
from .params import FlockParams

NO_GOAL = -1
Edge = tuple[int, int]


def mask_of(ids: Iterable[int]) -> int:
    mask = 0
    for k in ids:
        mask |= 1 << int(k)
    return mask


def ids_of(mask: int) -> list[int]:
    return [k for k in range(mask.bit_length()) if mask >> k & 1]


def merge_achieved(own: int, neighbours: Iterable[int]) -> int:
    """Gossip step: what I know is achieved, united with what my neighbours told me."""
    for m in neighbours:
        own |= int(m)
    return own


class ClusterMap:
    """Cluster centroids known to every MAP (from an aerial survey, Section IV-B), with cached MSTs."""

    def __init__(self, centroids_xy: np.ndarray, height: float) -> None:
        self.xy = np.asarray(centroids_xy, dtype=float).reshape(-1, 2)
        self.count = len(self.xy)
        self.targets = np.column_stack([self.xy, np.full(self.count, float(height))])
        self._mst = lru_cache(maxsize=None)(self._mst_uncached)

    def mst(self, achieved: int) -> tuple[Edge, ...]:
        """Edges (a < b) of the minimum spanning tree T_c over the achieved clusters, by centroid distance."""
        return self._mst(achieved)

    def _mst_uncached(self, achieved: int) -> tuple[Edge, ...]:
        ids = ids_of(achieved)
        if len(ids) < 2:
            return ()
        pts = self.xy[ids]
        dist = np.linalg.norm(pts[:, None, :] - pts[None, :, :], axis=-1)
        tree = minimum_spanning_tree(np.triu(dist)).tocoo()
        return tuple(sorted((min(ids[i], ids[j]), max(ids[i], ids[j])) for i, j in zip(tree.row, tree.col)))

    def nearest(self, q: np.ndarray, exclude: int) -> int:
        """Nearest cluster centre not in the mask exclude, or NO_GOAL if every cluster is in it."""
        free = [k for k in range(self.count) if not exclude >> k & 1]
        if not free:
            return NO_GOAL
        dist = np.linalg.norm(self.xy[free] - np.asarray(q, dtype=float)[:2], axis=1)
        return free[int(np.argmin(dist))]

    def segment_distance(self, q: np.ndarray, edge: Edge) -> float:
        """Horizontal distance from q to the segment between the centres of edge."""
        a, b = self.xy[edge[0]], self.xy[edge[1]]
        ab = b - a
        t = np.clip(np.dot(np.asarray(q, dtype=float)[:2] - a, ab) / max(np.dot(ab, ab), 1e-12), 0.0, 1.0)
        return float(np.linalg.norm(a + t * ab - np.asarray(q, dtype=float)[:2]))

    def nearest_edge(self, q: np.ndarray, edges: Iterable[Edge]) -> Optional[Edge]:
        return min(edges, key=lambda e: (self.segment_distance(q, e), e), default=None)

    def shared_edge(self, agent_id: int, edges: tuple[Edge, ...]) -> Edge:
        """The edge whose slice of [0, 1), sized by edge length, holds this MAP's key.

        Keys frac(id * golden ratio) spread evenly over [0, 1) for any set of ids, so the M1 MAPs split
        over the MST edges in proportion to the length each must bridge, with no message exchanged;
        when the tree grows, only MAPs whose slice moved change edge.
        """
        lengths = np.array([np.linalg.norm(self.xy[a] - self.xy[b]) for a, b in edges])
        bounds = np.cumsum(lengths) / lengths.sum()
        key = (agent_id * 0.6180339887498949) % 1.0
        return edges[min(int(np.searchsorted(bounds, key, side='right')), len(edges) - 1)]


class Memory(NamedTuple):
    """What a MAP carries from step to step: its mode M_i, goal g_c^i, known achieved goals and bridge."""

    mode: int = M0
    goal: int = NO_GOAL
    achieved: int = 0
    bridge: Optional[Edge] = None


def mode_switch(mem: Memory, n_users: int, goal_coverage: float, q: np.ndarray,
                clusters: ClusterMap, p: FlockParams) -> Memory:
    """Algorithm 2 for one MAP at one step, with the paper's open cases resolved by the policies in p.

    goal_coverage is r_g^i, the served fraction of the current goal cluster.
    """
    if mem.goal == NO_GOAL:  # first step: the nearest uncovered cluster (any cluster if all are covered)
        nxt = clusters.nearest(q, mem.achieved)
        return mem._replace(goal=nxt if nxt != NO_GOAL else clusters.nearest(q, 0))
    if not goal_coverage > p.r0:
        return mem
    if not mem.achieved >> mem.goal & 1:
        mem = mem._replace(achieved=mem.achieved | 1 << mem.goal)
    if mem.mode != M0:
        return mem
    if 0 < n_users < p.n0 or (n_users == 0 and p.zero_users == 'move_on'):
        nxt = clusters.nearest(q, mem.achieved)
        if nxt != NO_GOAL:
            return mem._replace(goal=nxt)
        if p.m0_exhausted == 'bridge' and len(clusters.mst(mem.achieved)) > 0:
            return mem._replace(mode=M1)
        return mem
    if p.n0 <= n_users < p.n1:
        return mem._replace(mode=M1)
    return mem._replace(mode=M2)


def choose_bridge(mem: Memory, agent_id: int, q: np.ndarray, clusters: ClusterMap, p: FlockParams) -> Memory:
    """Which MST edge an M1 MAP bridges, by p.edge_choice: the nearest (re-chosen each step or kept
    while in the tree), or its share of the tree by edge length."""
    if mem.mode != M1:
        return mem if mem.bridge is None else mem._replace(bridge=None)
    edges = clusters.mst(mem.achieved)
    if not edges:
        if p.m1_pending == 'lead' and mem.goal != NO_GOAL:
            ahead = clusters.nearest(q, mem.achieved)
            if ahead != NO_GOAL:
                return mem._replace(bridge=(mem.goal, ahead))
        return mem._replace(bridge=None) if mem.bridge is not None else mem
    if p.edge_choice == 'share':
        edge = clusters.shared_edge(agent_id, edges)
    elif p.edge_choice == 'keep_nearest' and mem.bridge in edges:
        return mem
    else:
        edge = clusters.nearest_edge(q, edges)
    return mem if edge == mem.bridge else mem._replace(bridge=edge)


def decide(mem: Memory, agent_id: int, n_users: int, cluster_coverage: np.ndarray, q: np.ndarray,
           neighbour_achieved: Iterable[int], clusters: ClusterMap, p: FlockParams) -> Memory:
    """One MAP's discrete update at step k: gossip, Algorithm 2, then the bridge it flies to."""
    achieved = merge_achieved(mem.achieved, neighbour_achieved)
    if achieved != mem.achieved:
        mem = mem._replace(achieved=achieved)
    r_g = float(cluster_coverage[mem.goal]) if mem.goal != NO_GOAL else 0.0
    mem = mode_switch(mem, n_users, r_g, q, clusters, p)
    return choose_bridge(mem, agent_id, q, clusters, p)


def reference(mem: Memory, clusters: ClusterMap) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(q^r, q_1^r, q_2^r, mode for eq. 9): M1 without a bridge holds at its goal like M2."""
    here = clusters.targets[mem.goal] if mem.goal != NO_GOAL else np.full(3, np.nan)
    if mem.mode == M1 and mem.bridge is not None:
        return here, clusters.targets[mem.bridge[0]], clusters.targets[mem.bridge[1]], M1
    return here, here, here, (M2 if mem.mode == M1 else mem.mode)
