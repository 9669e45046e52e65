"""The demand allocation's roles: every cluster and every edge of the tree, each with its demand in MAPs and
its pieces of the key line [0, 1), laid out afresh at the first survey and carried across later ones.

A MAP's role is the one whose pieces hold its key (clusters.key_of). Every MAP lays the roles out itself,
from the surveys it has heard; MAPs that heard the same surveys hold the same roles, with no message
exchanged.
"""
from __future__ import annotations

import bisect
import math
from typing import NamedTuple, Sequence

import numpy as np

from ...clusters import ClusterMap, Edge, tree_links
from . import keys
from ...ablation import on

SLACK = 0.3  # a cluster keeps servers down to its proportional share / (1 + SLACK) (kept)
STANDING = 10  # surveys an edge that left the tree keeps its relays while its replacement forms (standing)


def roles(clusters: ClusterMap, d: float, near: bool = False) -> 'Roles':
    """Every cluster and every edge of the MST over all clusters, with its demand in MAPs and its keys; laid
    out once per survey (ClusterMap.derived), from the roles of the survey before (ClusterMap.previous).
    near: a new role's MAPs come from the clusters nearest it on the tree (rule 'nearest', a lagged vehicle's)."""
    key = ('demand.roles', float(d), near)
    if key not in clusters.derived:
        clusters.derived[key] = _laid_out(clusters, float(d), near)
    return clusters.derived[key]


def _laid_out(now: ClusterMap, d: float, near: bool) -> 'Roles':
    """roles(), uncached."""
    tree = now.mst(now.live)
    previous, now.previous = now.previous, None
    was = roles(previous, d, near) if previous is not None else None
    stand = standing(was, tree, now, near) if was is not None and on('standing') else ()
    edges = tree + tuple(e for e, _ in stand)
    cell = math.sqrt(3.0) / 2.0 * d * d  # area per MAP of a hexagonal lattice of spacing d
    demand = [max(math.pi * r * r / cell, 1.0) if now.live >> k & 1 else 0.0  # every cluster at least one
              for k, r in enumerate(now.radii)]
    for e in edges:
        start, stop = now.gap(e, d / 2)
        demand.append((stop - start) / d)
    weights = np.array(demand)
    weights[len(weights) - len(stand):] = 0.0  # a standing chain keeps what it holds (below)
    if not np.any(now.radii > 0):  # nothing known of the clusters' extent: an equal share each, no relays
        weights = np.r_[[float(now.live >> k & 1) for k in range(now.count)], np.zeros(len(edges))]
    ids: list[keys.RoleId] = [*range(now.count), *edges]
    before = was.pieces if was is not None else ()
    if not weights.sum() > 0:  # no cluster exists (none has arrived yet, or all have left): keep the keys
        return Roles(edges, tuple(demand), (0.0,) * len(weights), before, stand)
    bounds = np.cumsum(weights) / weights.sum()
    starts = np.r_[0.0, bounds[:-1]]
    share = tuple(float(b - a) for a, b in zip(starts, bounds))
    if was is not None and before:
        for e, n in was.standing:  # an edge whose replacement stands: its relays join its two clusters
            if n == 1 and e not in edges and now.ends_live(e):
                before = keys.halved(before, e, e[0], e[1])
        held = keys.totals(before)
        lenders: list[int] = []
        arrived: list[int] = []
        joined = [k for e in tree if e not in was.edges for k in e]
        if stand:  # a standing chain keeps what it holds, lent by the clusters above their floor (kept)
            fixed = {e for e, _ in stand}
            share = tuple(held.get(r, 0.0) if r in fixed else s for r, s in zip(ids, share))
            lenders = by_hops(tree, joined)
        elif near:  # rule 'nearest': a new edge or cluster takes its share from the clusters nearest it first
            arrived = [k for k in range(now.count) if now.live >> k & 1 and held.get(k, 0.0) <= 0.0]
            lenders = by_hops(tree, joined + arrived)
        share = kept(share, ids, held, SLACK if on('kept') else 1e-9, lenders)
        pieces = keys.carry(before, dict(zip(ids, share))) if on('carry') else \
            keys.fresh(keys.end_to_end(dict(zip(ids, share))))
        if near and on('cascade'):
            pieces = cascaded(before, pieces, now, arrived, ids)
    else:
        pieces = keys.fresh(zip(ids, starts.tolist(), bounds.tolist()))
    return Roles(edges, tuple(demand), share, pieces, stand)


def standing(was: 'Roles', tree: tuple[Edge, ...], now: ClusterMap,
             swapped: bool = False) -> tuple[tuple[Edge, int], ...]:
    """Edges that left the tree but keep their relays, each with the surveys it has left (make before break).

    When a drifting cluster changes the tree and the edge that leaves shares no cluster with any edge that
    joins, no relay can swing (demand.pivot): its relays flew along the tree to the new edge and the two
    halves of the formation were apart until the new chain stood, 8-12 s for 150-200 m (docs/dynamics.md,
    "Make before break"). Such an edge now keeps its relays for STANDING surveys, while the new edge takes
    its share from the roles above theirs and the clusters lend it their slack (kept); then its relays join
    its two clusters (keys.halved; on a lagged vehicle each the nearer, demand.rejoined).

    swapped: a swapped edge (one that shares a cluster with an edge that joins) stands too, as a lagged
    vehicle lays the roles out (rule 'nearest'). Its relays would swing about the shared cluster, and on a
    lagged vehicle a swing is break before make: until the chain's far end reaches its new cluster, the side
    of the tree it bridged is cut off (9-14 m/s for 1-2 s, docs/notes/vehicle.md).
    """
    old = was.edges[:len(was.edges) - len(was.standing)]
    joined = [e for e in tree if e not in old]
    ends = {k for e in joined for k in e}
    left = [(e, STANDING) for e in old if e not in tree and (swapped or not ends & set(e))]
    going = [(e, n - 1) for e, n in was.standing if n > 1 and e not in tree]
    return tuple((e, n) for e, n in sorted(left + going) if now.ends_live(e))


def cascaded(old: tuple[keys.Piece, ...], new: tuple[keys.Piece, ...], now: ClusterMap,
             arrived: list[int], ids: Sequence[keys.RoleId]) -> tuple[keys.Piece, ...]:
    """Rule 'cascade': the keys a role of the tree takes from a cluster more than one hop away on it pass hop by hop
    instead: each cluster on the way gives as many of its own to the one before it and takes the farther one's, so
    every MAP that changes role crosses one hop, and all cross at once. An arriving cluster and its edges first,
    then the other roles of ids in order (a standing edge, out of the tree, keeps what it holds).

    Laid out as `kept` lends, an arrival's servers came from its neighbour down to its floor and from the cluster
    beyond: those flew 200-250 m, crawling through their own lattice first, and the arrival was covered 25-37 s
    after it came (docs/notes/vehicle.md, "Where an arrival's time goes"). An edge that joined the tree as a cluster
    drifted was staffed alike from two and three hops off: its chain was still not laid when the edge it replaced
    was let go, 20 s later, and the formation split (notes, "Rule `cascade` for every role"). Shares stay as `kept`
    laid them out. A cluster on the way that holds none of its own keys any more (an arrival larger than it took
    them all) is flown over, so what passes it crosses two hops, not all the way from the far end of the tree.
    """
    pieces = new
    tree = now.mst(now.live)
    first = [*arrived, *(e for e in tree if set(e) & set(arrived))]
    for role in [*first, *(r for r in ids if r not in first and (isinstance(r, int) or r in tree))]:
        for source, amount in sorted(keys.came_from(old, pieces, role).items(), key=lambda kv: str(kv[0])):
            if not isinstance(source, int) or source == role or not now.live >> source & 1:
                continue  # a relay's keys move as they did; so do a role's own, and an ended cluster's
            ways = [path(now, end, source) for end in ([role] if isinstance(role, int) else role)]
            way = min(ways, key=lambda w: (len(w), w))  # [an end of role, ..., source]
            hops = way if isinstance(role, int) else [role, *way]
            for _ in hops[1:-1]:  # each pass uses up what one cluster on the way holds of its own, or the amount
                own = {c: keys.came_from(old, pieces, c).get(c, 0.0) for c in hops[1:-1]}
                via = [hops[0], *(c for c in hops[1:-1] if own[c] > keys.SLIVER / 2), hops[-1]]
                if len(via) <= 2 or amount <= keys.SLIVER / 2:
                    break  # from a neighbour (one hop already), or nothing left to pass
                step = min(amount, *(own[c] for c in via[1:-1]))
                for near_one, far_one in zip(via[:-2], via[1:-1]):
                    pieces = keys.handed(pieces, far_one, near_one, step, old, far_one)
                pieces = keys.handed(pieces, role, via[-2], step, old, source)
                amount -= step
    return pieces


def path(now: ClusterMap, start: int, goal: int) -> list[int]:
    """The clusters on the tree's path from start to goal, both included (ClusterMap.tree_hop, as MAPs in transit
    fly it)."""
    out = [start]
    while out[-1] != goal:
        out.append(now.tree_hop(out[-1], goal))
    return out


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
    in transit alone (docs/notes/dynamics.md, "Kept shares"). Here a role keeps what it holds down to a floor, its
    proportional share / (1 + slack) for a cluster it served before, the whole share for an edge (a chain
    short of relays breaks) and for a new cluster (an arrival must be covered); a role below its floor takes
    what it lacks from the roles most above their proportional share. A standing chain (layout.standing)
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


class Roles(NamedTuple):
    """Roles 0..K-1 serve cluster k; role K + j relays on edges[j]. Role i owns the keys of its pieces of
    [0, 1), share[i] in all: end to end at the first survey, carried across later ones (keys.carry)."""

    edges: tuple[Edge, ...]
    demand: tuple[float, ...]   # MAPs each role needs (a lattice of spacing d over the disc, a chain over the gap)
    share: tuple[float, ...]
    pieces: tuple[keys.Piece, ...]
    # Edges out of the tree kept while their replacement forms, with the surveys each has left (last in edges).
    standing: tuple[tuple[Edge, int], ...] = ()

    @property
    def ids(self) -> tuple[keys.RoleId, ...]:
        """Every role in role order: the clusters' ids, then the edges."""
        return (*range(len(self.demand) - len(self.edges)), *self.edges)

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
