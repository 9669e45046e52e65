"""Cluster geometry every MAP shares: the surveyed clusters, the minimum spanning tree over them, and the roles
(a cluster to serve, a tree edge to relay on) that an allocation may hand out by key.

Achieved-goal sets travel as bit masks (bit k = cluster k achieved): gossip is then a bitwise OR, the
"merge by union" of the paper's shared list of achieved goals (Algorithm 2).
"""
from __future__ import annotations

import bisect
import math
from functools import lru_cache
from typing import Iterable, NamedTuple, Optional, Sequence

import numpy as np
from scipy.sparse.csgraph import minimum_spanning_tree

from . import keys
from .ablation import on

NO_GOAL = -1
Edge = tuple[int, int]
LINEAGE_MARGIN = 10.0  # m beyond two clusters' radii within which one continues the other (clusters.lineage)
SLACK = 0.3  # a cluster keeps servers down to its proportional share / (1 + SLACK) (clusters.kept)
STANDING = 10  # surveys an edge that left the tree keeps its relays while its replacement forms (clusters.standing)
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
        self._roles = lru_cache(maxsize=None)(self._roles_uncached)
        self._hops = lru_cache(maxsize=None)(self._hops_uncached)
        self._axes: dict[Edge, tuple[np.ndarray, np.ndarray, float]] = {}
        # The survey before this one, as this MAP heard it: roles carry their keys over from it (keys.carry).
        # Dropped once this map's roles are laid out; an allocation that never lays them out keeps one
        # survey back, not a chain, so a MAP never holds more than two surveys.
        self._previous = previous
        if previous is not None:
            previous._previous = None

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

    def roles(self, d: float) -> 'Roles':
        """Every cluster and every edge of the MST over all clusters, with its demand in MAPs and its keys."""
        return self._roles(float(d))

    def _roles_uncached(self, d: float) -> 'Roles':
        tree = self.mst(self.live)
        previous, self._previous = self._previous, None
        was = previous.roles(d) if previous is not None else None
        stand = standing(was, tree, self) if was is not None and on('standing') else ()
        edges = tree + tuple(e for e, _ in stand)
        cell = math.sqrt(3.0) / 2.0 * d * d  # area per MAP of a hexagonal lattice of spacing d
        demand = [max(math.pi * r * r / cell, 1.0) if self.live >> k & 1 else 0.0  # every cluster at least one
                  for k, r in enumerate(self.radii)]
        for e in edges:
            start, stop = self.gap(e, d / 2)
            demand.append((stop - start) / d)
        weights = np.array(demand)
        weights[len(weights) - len(stand):] = 0.0  # a standing chain keeps what it holds (below)
        if not np.any(self.radii > 0):  # nothing known of the clusters' extent: an equal share each, no relays
            weights = np.r_[[float(self.live >> k & 1) for k in range(self.count)], np.zeros(len(edges))]
        ids: list[keys.RoleId] = [*range(self.count), *edges]
        before = was.pieces if was is not None else ()
        if not weights.sum() > 0:  # no cluster exists (none has arrived yet, or all have left): keep the keys
            return Roles(edges, tuple(demand), (0.0,) * len(weights), before, stand)
        bounds = np.cumsum(weights) / weights.sum()
        starts = np.r_[0.0, bounds[:-1]]
        share = tuple(float(b - a) for a, b in zip(starts, bounds))
        if was is not None and before:
            for e, n in was.standing:  # an edge whose replacement stands: its relays join its two clusters
                if n == 1 and e not in edges and self.ends_live(e):
                    before = keys.halved(before, e, e[0], e[1])
            held = keys.totals(before)
            lenders: list[int] = []
            if stand:  # a standing chain keeps what it holds, lent by the clusters above their floor (kept)
                fixed = {e for e, _ in stand}
                share = tuple(held.get(r, 0.0) if r in fixed else s for r, s in zip(ids, share))
                lenders = by_hops(tree, [k for e in tree if e not in was.edges for k in e])
            share = kept(share, ids, held, SLACK if on('kept') else 1e-9, lenders)
            pieces = keys.carry(before, dict(zip(ids, share)),
                                *(lineage(previous, self, tree) if on('lineage') else ({}, {})))
        else:
            pieces = keys.fresh(zip(ids, starts.tolist(), bounds.tolist()))
        return Roles(edges, tuple(demand), share, pieces, stand)


def standing(was: 'Roles', tree: tuple[Edge, ...], now: ClusterMap) -> tuple[tuple[Edge, int], ...]:
    """Edges that left the tree but keep their relays, each with the surveys it has left (make before break).

    When a drifting cluster changes the tree and the edge that leaves shares no cluster with any edge that
    joins, no relay can swing (demand.pivot): its relays flew along the tree to the new edge and the two
    halves of the formation were apart until the new chain stood, 8-12 s for 150-200 m (docs/dynamics.md,
    "Make before break"). Such an edge now keeps its relays for STANDING surveys, while the new edge takes
    its share from the roles above theirs and the clusters lend it their slack (kept); then its relays join
    its two clusters (keys.halved).
    """
    old = was.edges[:len(was.edges) - len(was.standing)]
    joined = [e for e in tree if e not in old]
    ends = {k for e in joined for k in e}
    left = [(e, STANDING) for e in old if e not in tree and not ends & set(e)]
    going = [(e, n - 1) for e, n in was.standing if n > 1 and e not in tree]
    return tuple((e, n) for e, n in sorted(left + going) if now.ends_live(e))


def tree_links(tree: Iterable[Edge]) -> dict[int, list[int]]:
    """Each cluster's neighbours in the tree, in id order."""
    links: dict[int, list[int]] = {}
    for a, b in tree:
        links.setdefault(a, []).append(b)
        links.setdefault(b, []).append(a)
    return {k: sorted(v) for k, v in links.items()}


def by_hops(tree: tuple[Edge, ...], start: list[int]) -> list[int]:
    """The clusters of the tree in order of hops from the nearest of start (breadth first, ties by id)."""
    links = tree_links(tree)
    order = sorted(set(start))
    for c in order:
        order += [n for n in links.get(c, []) if n not in order]
    return order


def kept(share: tuple[float, ...], ids: list[keys.RoleId], held: dict[keys.RoleId, float],
         slack: float, lenders: Sequence[int] = ()) -> tuple[float, ...]:
    """The shares to lay out, given the proportional ones (share) and what each role held before (held).

    Proportional shares follow every change of surveyed demand: a drifting cluster whose 95 % disc shrank
    and grew back sent its servers across the field to the other clusters and called them back, each a MAP
    in transit alone (docs/dynamics.md, "Kept shares"). Here a role keeps what it holds down to a floor, its
    proportional share / (1 + slack) for a cluster it served before, the whole share for an edge (a chain
    short of relays breaks) and for a new cluster (an arrival must be covered); a role below its floor takes
    what it lacks from the roles most above their proportional share. A standing chain (clusters.standing)
    comes with its share on top: the clusters lend it their slack above their floors, those nearest the new
    edge on the tree first (lenders), so that its servers step out into the new chain from its ends.
    """
    if slack <= 0 or all(abs(held.get(r, 0.0) - s) < 1e-9 for r, s in zip(ids, share)):
        return share  # proportional; or nothing changed: the layout as it was, to the bit
    floor = [s / (1.0 + slack) if isinstance(r, int) and held.get(r, 0.0) > 0 else s for r, s in zip(ids, share)]
    out = [max(held.get(r, 0.0), f) if s > 0 else 0.0 for r, s, f in zip(ids, share, floor)]
    total = sum(out)
    for i in lenders:  # a standing chain's share comes first from the clusters nearest the new edge, to their floor
        if total <= 1.0 + 1e-12:
            break
        give = min(total - 1.0, max(out[i] - floor[i], 0.0))
        out[i] -= give
        total -= give
    if total > 1.0:
        over = sorted(range(len(out)), key=lambda i: share[i] - out[i])
        for i in over:
            give = min(total - 1.0, max(out[i] - share[i], 0.0))
            out[i] -= give
            total -= give
            if total <= 1.0 + 1e-12:
                break
        if total > 1.0 + 1e-12:  # shares summing to more than 1 (a standing chain's): clusters lend their slack
            slack_of = [max(o - f, 0.0) if isinstance(r, int) else 0.0 for r, o, f in zip(ids, out, floor)]
            spare = sum(slack_of)
            lend = min(total - 1.0, spare)
            if lend > 0:
                out = [o - lend * w / spare for o, w in zip(out, slack_of)]
                total -= lend
            if total > 1.0 + 1e-12:  # not slack enough: every role gives alike
                out = [o / total for o in out]
    elif total < 1.0:  # keys of roles that ended: to the roles below their share, as far as each lacks
        short = [max(s - o, 0.0) for s, o in zip(share, out)]
        lack = sum(short)  # >= 1 - total, since the shares sum to 1
        out = [o + (1.0 - total) * w / lack for o, w in zip(out, short)]
    return tuple(out)


def lineage(before: ClusterMap, now: ClusterMap, edges: tuple[Edge, ...]
            ) -> tuple[dict[keys.RoleId, keys.RoleId], dict[keys.RoleId, keys.RoleId]]:
    """Which roles of survey `now` continue which of survey `before` (heirs: ended -> continuing role;
    parents: new -> the role it splits from), read from where the clusters are: keys.carry step 0.

    The survey tracks each cluster by its centroid, so when two clusters merge one id goes on and the other
    ends, and when one splits the part that moves off takes a new id. Without lineage the ended cluster's
    servers, already over the merged users, were sent to whatever role their keys fell in, while the grown
    cluster drew new servers from its neighbours on the key line, wherever they were; a split did the same
    the other way round (docs/dynamics.md, "Merges and splits").
    - An ended cluster's heir is the live cluster nearest its last centroid within the two radii plus
      LINEAGE_MARGIN; an ended edge's heir is the tree edge between its ends' heirs (or ends), if any.
    - A new cluster's parent is the cluster live in both surveys nearest it, within the same reach.
    """
    heirs: dict[keys.RoleId, keys.RoleId] = {}
    parents: dict[keys.RoleId, keys.RoleId] = {}
    was = [k for k in range(before.count) if before.live >> k & 1]
    stays = [k for k in was if k < now.count and now.live >> k & 1]
    for k in was:
        if k not in stays:
            heir = _within_reach(before.xy[k], before.radii[k], now, ids_of(now.live))
            if heir is not None:
                heirs[k] = heir
    for k in ids_of(now.live):
        if not (k < before.count and before.live >> k & 1):
            parent = _within_reach(now.xy[k], now.radii[k], before, stays)
            if parent is not None:
                parents[k] = parent
    if heirs:
        tree = set(edges)
        for a, b in before.mst(before.live):
            ha, hb = heirs.get(a, a), heirs.get(b, b)
            edge = (min(ha, hb), max(ha, hb))
            if (a, b) not in tree and (a in heirs or b in heirs) and ha != hb and edge in tree:
                heirs[(a, b)] = edge
    return heirs, parents


def _within_reach(xy: np.ndarray, radius: float, other: ClusterMap, among: Iterable[int]) -> Optional[int]:
    """The cluster of `among` in survey `other` nearest xy, if within the two radii plus LINEAGE_MARGIN."""
    near = [(float(np.linalg.norm(other.xy[j] - xy)), j) for j in among]
    near = [(dist, j) for dist, j in near if dist <= radius + other.radii[j] + LINEAGE_MARGIN]
    return min(near)[1] if near else None


class Roles(NamedTuple):
    """Roles 0..K-1 serve cluster k; role K + j relays on edges[j]. Role i owns the keys of its pieces of
    [0, 1), share[i] in all: end to end at the first survey, carried across later ones (keys.carry)."""

    edges: tuple[Edge, ...]
    demand: tuple[float, ...]   # MAPs each role needs (a lattice of spacing d over the disc, a chain over the gap)
    share: tuple[float, ...]
    pieces: tuple[keys.Piece, ...]
    # Edges out of the tree kept while their replacement forms, with the surveys each has left (last in edges).
    standing: tuple[tuple[Edge, int], ...] = ()

    def index(self, role: keys.RoleId) -> int:
        """Role number of a cluster id or an edge."""
        return role if isinstance(role, int) else len(self.demand) - len(self.edges) + self.edges.index(role)

    def of(self, key: float) -> int:
        """The role whose piece holds key."""
        i = bisect.bisect_right(self.pieces, key, key=lambda p: p[0])
        return self.index(self.pieces[max(i - 1, 0)][2])

    def place(self, key: float, role: int) -> float:
        """Where among its role's keys key lies, 0..1: a relay's position along its gap."""
        mine = [(lo, hi) for lo, hi, r in self.pieces if self.index(r) == role]
        if len(mine) == 1:
            lo, hi = mine[0]
            return float(np.clip((key - lo) / (hi - lo), 0.0, 1.0))
        total = sum(hi - lo for lo, hi in mine)
        below = sum(min(max(key - lo, 0.0), hi - lo) for lo, hi in mine)
        return float(np.clip(below / total, 0.0, 1.0)) if total > 0 else 0.5
