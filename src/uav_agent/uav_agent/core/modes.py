"""The mode switch and goals of one MAP: the paper's Algorithm 2 and the demand allocation.

Algorithm 2 (`allocation: algorithm2`) grows the MST over achieved clusters and sends M1 MAPs to its
edges. The demand allocation (`allocation: demand`, docs/allocation.md) gives every MAP one role from the
start, a cluster to serve or an edge of the MST over all clusters to relay on, by the share of [0, 1) its
id's key falls in, with shares sized by each role's demand in MAPs.

Achieved-goal sets travel as bit masks (bit k = cluster k achieved): gossip is then a bitwise OR, the
"merge by union" of the paper's shared list of achieved goals.
"""
from __future__ import annotations

import bisect
import math
from functools import lru_cache
from typing import Iterable, NamedTuple, Optional, Sequence

import numpy as np
from scipy.sparse.csgraph import minimum_spanning_tree

from . import keys
from .control import M0, M1, M2
from .params import FlockParams

NO_GOAL = -1
Edge = tuple[int, int]
GOLDEN = 0.6180339887498949  # frac(id * GOLDEN) spreads any set of ids evenly over [0, 1)
STALL_STEPS = 50             # steps without a 1 % gain after which a goal's coverage counts as stalled
STALL_GAIN = 0.01


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
        # Dropped once this map's roles are laid out, so a MAP never holds more than two surveys.
        self._previous = previous

    def mst(self, achieved: int) -> tuple[Edge, ...]:
        """Edges (a < b) of the minimum spanning tree T_c over the achieved clusters that exist, by centroid
        distance."""
        return self._mst(achieved & self.live)

    def _mst_uncached(self, achieved: int) -> tuple[Edge, ...]:
        ids = ids_of(achieved)
        return tuple(sorted((min(ids[i], ids[j]), max(ids[i], ids[j])) for i, j in mst_edges(self.xy[ids])))

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
        links: dict[int, list[int]] = {}
        for a, b in self.mst(self.live):
            links.setdefault(a, []).append(b)
            links.setdefault(b, []).append(a)
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
        edges = self.mst(self.live)
        cell = math.sqrt(3.0) / 2.0 * d * d  # area per MAP of a hexagonal lattice of spacing d
        demand = [max(math.pi * r * r / cell, 1.0) if self.live >> k & 1 else 0.0  # every cluster at least one
                  for k, r in enumerate(self.radii)]
        for e in edges:
            start, stop = self.gap(e, d / 2)
            demand.append((stop - start) / d)
        weights = np.array(demand)
        if not np.any(self.radii > 0):  # nothing known of the clusters' extent: an equal share each, no relays
            weights = np.r_[[float(self.live >> k & 1) for k in range(self.count)], np.zeros(len(edges))]
        ids: list[keys.RoleId] = [*range(self.count), *edges]
        before = self._previous.roles(d).pieces if self._previous is not None else ()
        self._previous = None
        if not weights.sum() > 0:  # no cluster exists (none has arrived yet, or all have left): keep the keys
            return Roles(edges, tuple(demand), (0.0,) * len(weights), before)
        bounds = np.cumsum(weights) / weights.sum()
        starts = np.r_[0.0, bounds[:-1]]
        share = tuple(float(b - a) for a, b in zip(starts, bounds))
        if before:
            pieces = keys.carry(before, dict(zip(ids, share)))
        else:
            pieces = keys.fresh(zip(ids, starts.tolist(), bounds.tolist()))
        return Roles(edges, tuple(demand), share, pieces)


class Roles(NamedTuple):
    """Roles 0..K-1 serve cluster k; role K + j relays on edges[j]. Role i owns the keys of its pieces of
    [0, 1), share[i] in all: end to end at the first survey, carried across later ones (keys.carry)."""

    edges: tuple[Edge, ...]
    demand: tuple[float, ...]   # MAPs each role needs (a lattice of spacing d over the disc, a chain over the gap)
    share: tuple[float, ...]
    pieces: tuple[keys.Piece, ...]

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


class Memory(NamedTuple):
    """What a MAP carries from step to step: its mode M_i, goal g_c^i, known achieved goals and bridge,
    and (demand allocation) the best coverage of its goal so far, the steps since it last grew, and
    whether it has reached its role's place once, and whether it is on its way to a new role since
    (transit: a role change after settling, flown along the tree); a relay whose edge left the tree for
    one with a cluster in common swings about that cluster (swing: the pivot and its place along the gap)."""

    mode: int = M0
    goal: int = NO_GOAL
    achieved: int = 0
    bridge: Optional[Edge] = None
    best: float = 0.0
    flat: int = 0
    settled: bool = False
    transit: bool = False
    swing: Optional[tuple[int, float]] = None


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


def served(mem: Memory, r_g: float, arrived: bool, fp: FlockParams) -> Memory:
    """Track the goal's coverage: achieved above r0, or once it has stopped growing (a stall).

    A cluster whose MAPs are all in place but that stays just under r0 would otherwise never count as
    served; STALL_STEPS without a gain of STALL_GAIN, counted while this MAP is at the cluster (arrived),
    count it served, so it joins the achieved set.
    """
    if r_g > mem.best + STALL_GAIN:
        mem = mem._replace(best=r_g, flat=0)
    elif arrived and r_g > 0:
        mem = mem._replace(flat=mem.flat + 1)
    if (r_g > fp.r0 or mem.flat >= STALL_STEPS) and not mem.achieved >> mem.goal & 1:
        mem = mem._replace(achieved=mem.achieved | 1 << mem.goal)
    return mem


def demand_switch(mem: Memory, agent_id: int, r_g: float, q: np.ndarray, clusters: ClusterMap,
                  fp: FlockParams) -> Memory:
    """The demand allocation for one MAP at one step: its role from its key, then its mode.

    A server flies to its cluster in M0 and holds it in M2 once the cluster is served; a relay bridges
    its edge in M1 from the start, so the tree never waits for clusters to be achieved.
    """
    roles = clusters.roles(fp.d)
    if not clusters.live:  # no cluster to serve or bridge: hold where it is until one appears
        return mem if mem.goal == NO_GOAL and mem.mode == M2 else \
            Memory(mode=M2, achieved=mem.achieved, settled=mem.settled)
    role = roles.of(key_of(agent_id))
    if role < clusters.count:
        if mem.goal != role or mem.mode == M1:
            mem = Memory(mode=M0, goal=role, achieved=mem.achieved, settled=mem.settled, transit=mem.settled)
            r_g = 0.0
        arrived = float(np.hypot(*(np.asarray(q, dtype=float)[:2] - clusters.xy[role]))) <= clusters.radii[role]
        if arrived and (mem.transit or not mem.settled):
            mem = mem._replace(settled=True, transit=False)
        mem = served(mem, r_g, arrived, fp)
        if mem.mode == M0 and mem.achieved >> mem.goal & 1:
            mem = mem._replace(mode=M2)
        return mem
    edge = roles.edges[role - clusters.count]
    if mem.mode != M1 or mem.bridge != edge:
        mem = Memory(mode=M1, goal=edge[0], achieved=mem.achieved, bridge=edge, settled=mem.settled,
                     transit=mem.settled, swing=pivot(mem, q, edge, clusters, fp))
    if (mem.transit or not mem.settled) and clusters.segment_distance(q, edge) <= fp.d:
        mem = mem._replace(settled=True, transit=False)
    if mem.swing is not None:
        a, u, _ = clusters.axis(edge)
        if float(np.linalg.norm(a + u * swing_place(mem.swing, edge, clusters, fp) - np.asarray(q)[:2])) <= fp.d:
            mem = mem._replace(swing=None)
    return mem


def _gap_from(end: int, edge: Edge, clusters: ClusterMap, fp: FlockParams) -> tuple[float, float, float]:
    """(edge length, start, end of its gap), in m from the centre of its cluster `end`."""
    start, stop = clusters.gap(edge, fp.d / 2)
    length = clusters.axis(edge)[2]
    return (length, start, stop) if edge[0] == end else (length, length - stop, length - start)


def pivot(mem: Memory, q: np.ndarray, edge: Edge, clusters: ClusterMap, fp: FlockParams) -> Optional[tuple[int, float]]:
    """The swing a relay takes to edge: the cluster its old edge shares with it, and the relay's place along
    the old gap from that cluster (0..1); None if it was not settled on an edge that shares exactly one.

    When a drifting cluster changes the tree, relays of an edge that left it take the keys of one that joined.
    Keeping its place from the shared cluster P and flying straight there, each relay lands on the new edge
    about where the chain needs it, and those near P barely move: the new chain forms along its whole length
    at once, where flying along the tree (through P's centre and out) would grow it from one end, one relay
    at a time (docs/dynamics.md, "Swinging chains").
    """
    old = mem.bridge
    if mem.mode != M1 or old is None or not mem.settled or not all(clusters.live >> k & 1 for k in old):
        return None
    shared = set(old) & set(edge)
    if len(shared) != 1:
        return None
    p = shared.pop()
    length, lo, hi = _gap_from(p, old, clusters, fp)
    a, u, _ = clusters.axis(old)
    along = float(np.dot(np.asarray(q, dtype=float)[:2] - a, u))
    from_p = along if old[0] == p else length - along
    return p, float(np.clip((from_p - lo) / max(hi - lo, 1e-9), 0.0, 1.0))


def swing_place(swing: tuple[int, float], edge: Edge, clusters: ClusterMap, fp: FlockParams) -> float:
    """Where along edge (m from its first centre) a swinging relay aims: its old place, from the pivot."""
    p, f = swing
    length, lo, hi = _gap_from(p, edge, clusters, fp)
    from_p = lo + f * (hi - lo)
    return from_p if edge[0] == p else length - from_p


def decide(mem: Memory, agent_id: int, n_users: int, cluster_coverage: np.ndarray, q: np.ndarray,
           neighbour_achieved: Iterable[int], clusters: ClusterMap, fp: FlockParams) -> Memory:
    """One MAP's discrete update at step k: gossip, then Algorithm 2 and the bridge, or its demand role."""
    achieved = merge_achieved(mem.achieved, neighbour_achieved)
    if achieved != mem.achieved:
        mem = mem._replace(achieved=achieved)
    r_g = float(cluster_coverage[mem.goal]) if mem.goal != NO_GOAL else 0.0
    if fp.allocation == 'demand':
        return demand_switch(mem, agent_id, r_g, q, clusters, fp)
    mem = mode_switch(mem, n_users, r_g, q, clusters, fp)
    return choose_bridge(mem, agent_id, q, clusters, fp)


class Told(NamedTuple):
    """What a neighbour's state message says of its role: mode, goal and bridge (as of its last step)."""

    mode: int
    goal: int
    bridge: Optional[Edge]


def relay_place(agent_id: int, q: np.ndarray, edge: Edge, nbr_q: np.ndarray, told: Sequence[Told],
                clusters: ClusterMap, fp: FlockParams) -> float:
    """Where along its edge a relay aims (m from the first cluster's centre): midway along its chain.

    The chain of an edge (a, b) is its relays and the servers of a and b. Servers of a lie on the a side
    of every relay and servers of b on the b side, so the outermost server heard is each side's anchor.
    A relay that hears a chain member on each side aims midway between the nearest two, so the chain
    relaxes to even spacing between the clusters' outermost servers wherever they are; with one side
    silent it reaches d beyond the other towards the silent side; hearing none, it takes its own place in
    the gap by its key.
    """
    a, u, length = clusters.axis(edge)
    here = float(np.dot(np.asarray(q, dtype=float)[:2] - a, u))
    below, above = -math.inf, math.inf
    # How far along the edge a relay may aim and stay within reach (r less 1 m) of some server of each
    # cluster: a server off the axis reaches less far along it.
    reach_a, reach_b = -math.inf, math.inf
    for qj, tj in zip(nbr_q, told):
        if not _in_place(qj, tj, edge, clusters, fp):
            continue
        at = float(np.dot(qj[:2] - a, u))
        if tj.mode != M1 and tj.goal in edge:
            off = abs(float(u[0] * (qj[1] - a[1]) - u[1] * (qj[0] - a[0])))
            reach = math.sqrt(max((fp.r - 1.0) ** 2 - off * off, 0.0))
            if tj.goal == edge[0]:
                reach_a = max(reach_a, at + reach)
            else:
                reach_b = min(reach_b, at - reach)
        if tj.mode != M1 and tj.goal == edge[0] or tj.mode == M1 and tj.bridge == edge and at < here:
            below = max(below, at)
        elif tj.mode != M1 and tj.goal == edge[1] or tj.mode == M1 and tj.bridge == edge and at > here:
            above = min(above, at)
    if math.isfinite(below) and math.isfinite(above):
        mid = (below + above) / 2.0
        if reach_b <= reach_a:  # both ends within reach: stay where both hold
            return min(max(mid, reach_b), reach_a)
        return mid
    if math.isfinite(below):
        return min(below + fp.d, length)
    if math.isfinite(above):
        return max(above - fp.d, 0.0)
    roles = clusters.roles(fp.d)
    start, stop = clusters.gap(edge, fp.d / 2)
    return start + roles.place(key_of(agent_id), clusters.count + roles.edges.index(edge)) * (stop - start)


def _in_place(qj: np.ndarray, tj: 'Told', edge: Edge, clusters: ClusterMap, fp: FlockParams) -> bool:
    """Whether a neighbour is where its role holds it: a server within its cluster's disc (plus d/2), a relay
    within d of its edge. One still on its way (to a new role, or first out) would bend the chain towards it."""
    if tj.mode == M1:
        return tj.bridge == edge and clusters.segment_distance(qj, edge) <= fp.d
    if tj.goal not in edge:
        return False
    return float(np.hypot(*(qj[:2] - clusters.xy[tj.goal]))) <= clusters.radii[tj.goal] + fp.d / 2


def relay_slot(place: float, edge: Edge, clusters: ClusterMap, fp: FlockParams) -> tuple[np.ndarray, np.ndarray]:
    """q_1^r, q_2^r of eq. 13 for a relay: a piece of its edge d/2 long centred where it aims.

    E_c pulls the relay onto that piece and is flat along it, so the flocking terms keep their say there.
    """
    a, u, length = clusters.axis(edge)
    place = min(max(place, 0.0), length)
    lo, hi = max(place - fp.d / 4, 0.0), min(place + fp.d / 4, length)
    return (np.array([a[0] + u[0] * lo, a[1] + u[1] * lo, fp.height]),
            np.array([a[0] + u[0] * hi, a[1] + u[1] * hi, fp.height]))


def related(a: Told, b: Told) -> bool:
    """Whether two MAPs' roles belong together: one cluster's servers, or a relay and its edge's servers
    or fellow relays. Under the demand allocation only related MAPs attract (control.flocking_terms)."""
    if a.mode == M1 and b.mode == M1:
        return a.bridge == b.bridge
    if a.mode == M1:
        return a.bridge is not None and b.goal in a.bridge
    if b.mode == M1:
        return b.bridge is not None and a.goal in b.bridge
    return a.goal == b.goal


def apart_links(mem: Memory, heard: Sequence[Told], fp: FlockParams) -> list[bool]:
    """For each neighbour heard, whether its link to this MAP (as decided this step) joins unrelated roles;
    all False under Algorithm 2, whose flocking terms take every neighbour alike."""
    if fp.allocation != 'demand':
        return [False] * len(heard)
    own = Told(mem.mode, mem.goal, mem.bridge)
    return [not related(own, t) for t in heard]


def en_route(mem: Memory, q: np.ndarray, clusters: ClusterMap, fp: FlockParams) -> int:
    """The cluster a MAP in transit heads for first: the next one along the tree from the cluster it is at,
    or NO_GOAL to go straight to its role.

    A MAP in transit (demand allocation) left a place in a covered, connected formation because the clusters
    changed; flown straight to its new role it would cross empty ground out of everyone's range. Along the
    tree it passes clusters and relay chains. Roles never change while the clusters stand still, so then
    nothing is ever in transit.
    """
    if fp.allocation != 'demand' or not mem.transit or mem.goal == NO_GOAL or mem.swing is not None:
        return NO_GOAL
    if mem.mode == M1 and mem.bridge is not None:
        if clusters.segment_distance(q, mem.bridge) <= fp.d:
            return NO_GOAL
        a, b = clusters.xy[mem.bridge[0]], clusters.xy[mem.bridge[1]]
        xy = np.asarray(q, dtype=float)[:2]
        dest = mem.bridge[0] if np.linalg.norm(xy - a) <= np.linalg.norm(xy - b) else mem.bridge[1]
    else:
        dest = mem.goal
    at = clusters.nearest(q, 0)
    if at == NO_GOAL or at == dest:
        return NO_GOAL
    return clusters.tree_hop(at, dest)


class Reference(NamedTuple):
    """What eq. 9's goal term aims at: q^r (M0/M2), q_1^r and q_2^r (M1), the mode that picks between
    them, and the velocities the damping of eqs. 12-13 matches (rows: q^r, q_1^r, q_2^r)."""

    target: np.ndarray
    q1: np.ndarray
    q2: np.ndarray
    mode: int
    velocity: np.ndarray  # (3, 3)


def reference(mem: Memory, agent_id: int, q: np.ndarray, nbr_q: np.ndarray, told: Sequence[Told],
              clusters: ClusterMap, fp: FlockParams) -> Reference:
    """The goal term's reference: M1 without a bridge holds at its goal like M2; a MAP with no goal (no
    cluster exists) holds where it is.

    Under the demand allocation an M1 MAP bridges its own piece of the edge, where its chain needs it.
    """
    if mem.goal != NO_GOAL:
        here, v = clusters.targets[mem.goal], clusters.velocities[mem.goal]
    else:
        here, v = np.asarray(q, dtype=float), np.zeros(3)
    hop = en_route(mem, q, clusters, fp)
    if hop != NO_GOAL:
        at, v = clusters.targets[hop], clusters.velocities[hop]
        return Reference(at, at, at, M0, np.array([v, v, v]))
    if mem.mode == M1 and mem.bridge is not None:
        va, vb = clusters.velocities[mem.bridge[0]], clusters.velocities[mem.bridge[1]]
        if fp.allocation == 'demand':
            place = swing_place(mem.swing, mem.bridge, clusters, fp) if mem.swing is not None else \
                relay_place(agent_id, q, mem.bridge, nbr_q, told, clusters, fp)
            q1, q2 = relay_slot(place, mem.bridge, clusters, fp)
            # The slot moves as its point of the edge does: at the velocity interpolated between the ends.
            length = clusters.axis(mem.bridge)[2]
            vs = va + (min(max(place / length, 0.0), 1.0) if length > 0 else 0.5) * (vb - va)
            return Reference(here, q1, q2, M1, np.array([v, vs, vs]))
        return Reference(here, clusters.targets[mem.bridge[0]], clusters.targets[mem.bridge[1]], M1,
                         np.array([v, va, vb]))
    return Reference(here, here, here, (M2 if mem.mode == M1 else mem.mode), np.array([v, v, v]))
