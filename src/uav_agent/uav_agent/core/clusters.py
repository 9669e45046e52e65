"""Cluster geometry every MAP shares: the surveyed clusters, the minimum spanning tree over them, and where
along a tree edge things lie. Geometry only: what an allocation derives from it lives with the allocation
(core/allocations/), cached on the survey's ClusterMap (ClusterMap.derived).

Achieved-goal sets travel as bit masks (bit k = cluster k achieved): gossip is then a bitwise OR, the
"merge by union" of the paper's shared list of achieved goals (Algorithm 2).
"""
from __future__ import annotations

from functools import lru_cache
from typing import Any, Iterable, Optional

import numpy as np
from scipy.sparse.csgraph import minimum_spanning_tree

NO_GOAL = -1
Edge = tuple[int, int]
GOLDEN = 0.6180339887498949  # frac(id * GOLDEN) spreads any set of ids evenly over [0, 1)


def key_of(agent_id: int) -> float:
    """The MAP's key in [0, 1): golden-ratio keys of any ids are evenly spread (three-gap theorem)."""
    return (agent_id * GOLDEN) % 1.0


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


def mst_edges(xy: np.ndarray) -> list[Edge]:
    """Edges (a < b) of the Euclidean minimum spanning tree over the points xy, sorted."""
    if len(xy) < 2:
        return []
    dist = np.linalg.norm(xy[:, None, :] - xy[None, :, :], axis=-1)
    tree = minimum_spanning_tree(np.triu(dist)).tocoo()
    return sorted((int(min(i, j)), int(max(i, j))) for i, j in zip(tree.row, tree.col))


def segment_distance(point: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Horizontal distance from point to the segment a-b."""
    point = np.asarray(point, dtype=float)[:2]
    ab = b - a
    t = np.clip(np.dot(point - a, ab) / max(float(np.dot(ab, ab)), 1e-12), 0.0, 1.0)
    return float(np.linalg.norm(a + t * ab - point))


class ClusterMap:
    """Cluster centroids known to every MAP (from an aerial survey, Section IV-B), with cached MSTs."""

    def __init__(self, centroids_xy: np.ndarray, height: float, radii: Optional[np.ndarray] = None,
                 active: Optional[np.ndarray] = None, velocities: Optional[np.ndarray] = None,
                 previous: Optional['ClusterMap'] = None) -> None:
        self.xy = np.asarray(centroids_xy, dtype=float).reshape(-1, 2)
        self.count = len(self.xy)
        # R_k: radius of the disc holding 95 % of cluster k's MSDs (m), from the survey; 0 if unknown.
        self.radii = np.zeros(self.count) if radii is None else np.asarray(radii, dtype=float).reshape(self.count)
        # Clusters that exist now, as a mask: an online survey keeps an ended cluster's id (and its index
        # here) so that no other cluster's index moves, but nobody is sent to it.
        self.live = mask_of(range(self.count)) if active is None else mask_of(np.flatnonzero(active))
        self.active = np.array([bool(self.live >> k & 1) for k in range(self.count)], dtype=bool)
        self.targets = np.column_stack([self.xy, np.full(self.count, float(height))])
        # p^r of eqs. 12-13: each cluster's velocity (m/s) as the survey estimates it; zero when still.
        vxy = np.zeros((self.count, 2)) if velocities is None else np.asarray(velocities, dtype=float).reshape(-1, 2)
        self.velocities = np.column_stack([vxy, np.zeros(self.count)])
        self._mst = lru_cache(maxsize=None)(self._mst_uncached)
        self._hops = lru_cache(maxsize=None)(self._hops_uncached)
        self._axes: dict[Edge, tuple[np.ndarray, np.ndarray, float]] = {}
        # What an allocation derives from this survey (its roles, say), by a key of its own: computed once
        # per survey, by whichever MAP or simulator needs it first.
        self.derived: dict[Any, Any] = {}
        # The survey before this one, as this MAP heard it, for an allocation that carries something over
        # from it (demand: its roles' keys). The allocation drops it once used; one that never uses it keeps
        # one survey back, not a chain, so a MAP never holds more than two surveys.
        self.previous = previous
        if previous is not None:
            previous.previous = None

    def mst(self, achieved: int) -> tuple[Edge, ...]:
        """Edges (a < b) of the minimum spanning tree T_c over the achieved clusters that exist, by centroid
        distance."""
        return self._mst(achieved & self.live)

    def _mst_uncached(self, achieved: int) -> tuple[Edge, ...]:
        ids = ids_of(achieved)
        return tuple(sorted((min(ids[i], ids[j]), max(ids[i], ids[j])) for i, j in mst_edges(self.xy[ids])))

    def ends_live(self, edge: Edge) -> bool:
        """Whether both clusters of an edge still exist (an ended cluster's id stays, inactive)."""
        return all(self.live >> k & 1 for k in edge)

    def nearest(self, q: np.ndarray, exclude: int) -> int:
        """Nearest existing cluster centre not in the mask exclude, or NO_GOAL if every cluster is in it."""
        free = [k for k in range(self.count) if not exclude >> k & 1 and self.live >> k & 1]
        if not free:
            return NO_GOAL
        dist = np.linalg.norm(self.xy[free] - np.asarray(q, dtype=float)[:2], axis=1)
        return free[int(np.argmin(dist))]

    def tree_hop(self, here: int, there: int) -> int:
        """The next cluster after `here` on the path to `there` in the MST over the existing clusters."""
        return self._hops(here, there)

    def _hops_uncached(self, here: int, there: int) -> int:
        links = tree_links(self.mst(self.live))
        came = {there: there}
        todo = [there]
        while todo:  # breadth first from `there`: each cluster learns its next step towards it
            c = todo.pop(0)
            for n in links.get(c, []):
                if n not in came:
                    came[n] = c
                    todo.append(n)
        return came.get(here, there)

    def segment_distance(self, q: np.ndarray, edge: Edge) -> float:
        """Horizontal distance from q to the segment between the centres of edge."""
        return segment_distance(q, self.xy[edge[0]], self.xy[edge[1]])

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
        return edges[min(int(np.searchsorted(bounds, key_of(agent_id), side='right')), len(edges) - 1)]

    def axis(self, edge: Edge) -> tuple[np.ndarray, np.ndarray, float]:
        """(first cluster's centre, unit vector to the second, length in m): what places along an edge are
        measured on, once per edge."""
        if edge not in self._axes:
            a = self.xy[edge[0]]
            length = float(np.linalg.norm(self.xy[edge[1]] - a))
            self._axes[edge] = (a, (self.xy[edge[1]] - a) / max(length, 1e-12), length)
        return self._axes[edge]

    def gap(self, edge: Edge, inset: float) -> tuple[float, float]:
        """Where along an edge (m from the first centre) the stretch between its clusters' outermost servers
        starts and ends (the whole edge if they meet).

        Servers cover their cluster's 95 % disc from inside it: the outermost sit about inset (half a
        lattice spacing) inside the disc's edge, so that is where a relay chain must reach.
        """
        length = self.axis(edge)[2]
        ra, rb = max(self.radii[edge[0]] - inset, 0.0), max(self.radii[edge[1]] - inset, 0.0)
        return (0.0, length) if ra + rb >= length else (ra, length - rb)


def tree_links(tree: Iterable[Edge]) -> dict[int, list[int]]:
    """Each cluster's neighbours in the tree, in id order."""
    links: dict[int, list[int]] = {}
    for a, b in tree:
        links.setdefault(a, []).append(b)
        links.setdefault(b, []).append(a)
    return {k: sorted(v) for k, v in links.items()}
