"""The demand allocation (`allocation: demand`, docs/allocation.md): every MAP takes one role from the start,
a cluster to serve or an edge of the MST over all clusters to relay on, by the share of [0, 1) its id's
key falls in, with shares sized by each role's demand in MAPs. Relays space themselves along their edge's
gap, swing about a shared cluster when the tree changes (chain.py), and a MAP sent to a new role flies along
the tree."""
from __future__ import annotations

from typing import TYPE_CHECKING, Optional, Sequence

import numpy as np

from ... import envelope
from ...ablation import on
from ...clusters import NO_GOAL, ClusterMap
from ...state import (ALONE, APART, INLINE, M0, M1, M2, NOBODY, PASSING, RELATED, SHARED, UNKEPT, Memory, Near,
                      Reference, Told, aim, hold)
from .chain import anchored, chain_of, hushed, pivot, relay_place, relay_slot, swing_place, tally, taut
from .memory import Mine, gossip_of
from .vacancy import gossip, nearest, role_of, vacate, vanished

if TYPE_CHECKING:
    from ...params import FlockParams

def served(mem: Mine, r_g: float, fp: FlockParams) -> Mine:
    """The goal joins the achieved set once its coverage r_g passes r0 (Algorithm 2's test)."""
    if r_g > fp.r0 and not mem.achieved >> mem.goal & 1:
        mem = mem._replace(achieved=mem.achieved | 1 << mem.goal)
    return mem


def _anew(mem: Mine, **role: object) -> Mine:
    """A MAP's memory for a new role: what it knows of the clusters and the roles stays."""
    return Mine(achieved=mem.achieved, settled=mem.settled, seen=mem.seen, lost=mem.lost, short=mem.short,
                  since=mem.since, around=mem.around, **role)  # type: ignore[arg-type]


def rejoined(mem: Mine, role: int, edges: Sequence[tuple[int, int]], q: np.ndarray,
             clusters: ClusterMap) -> Optional[tuple[int, int]]:
    """Rule 'nearest' for a relay let go: (the cluster its key names, the one it joins), or None to join the one
    its key names. When a standing chain is let go (layout.standing) its keys split at their middle between its two
    clusters, but on a lagged vehicle a relay's place along the chain is its rank among the relays it hears
    (chain.ends_place), not its key: half of them crossed their whole chain to the far cluster, alone, out of
    everyone's range for seconds (docs/notes/vehicle.md). So a relay let go joins the nearer of its chain's two
    clusters by where it is, and stays with it while its key names the same cluster."""
    if mem.rejoin is not None and mem.rejoin[0] == role:
        return mem.rejoin
    if mem.mode != M1 or mem.bridge is None or role not in mem.bridge or mem.bridge in edges:
        return None
    ends = (role, mem.bridge[0] if role == mem.bridge[1] else mem.bridge[1])  # a tie stays with its key's
    at = np.asarray(q, dtype=float)[:2]
    nearer = min(ends, key=lambda c: float(np.hypot(*(at - clusters.xy[c]))))
    return role, nearer


def demand_switch(mem: Mine, agent_id: int, r_g: float, q: np.ndarray, clusters: ClusterMap, fp: FlockParams,
                  step: int = 0, near: Near = NOBODY) -> Mine:
    """The demand allocation for one MAP at one step: its role from its key, then its mode.

    A server flies to its cluster in M0 and holds it in M2 once the cluster is served; a relay bridges
    its edge in M1 from the start, so the tree never waits for clusters to be achieved. Keys known lost
    (vacancy.py) are squeezed out of the line first, so the survivors staff every role.
    """
    if not clusters.live:  # no cluster to serve or bridge: hold where it is until one appears
        return mem if mem.goal == NO_GOAL and mem.mode == M2 else _anew(mem, mode=M2)
    mem = vacate(mem, step, q, clusters, fp)
    roles, key = role_of(agent_id, mem.lost, clusters, fp, mem.short)
    role = roles.of(key)
    rejoin = rejoined(mem, role, roles.edges, q, clusters) if role < clusters.count and nearest(fp) else None
    if rejoin is not None:
        role = rejoin[1]
    if role < clusters.count:
        if mem.goal != role or mem.mode == M1:
            old = mem.bridge if mem.mode == M1 else None
            straight = (on('straight') and not envelope.limited(fp) and old is not None and role in old
                        and old not in roles.edges and clusters.ends_live(old))
            mem = _anew(mem, mode=M0, goal=role, transit=mem.settled, straight=straight, rejoin=rejoin)
            r_g = 0.0
        arrived = float(np.hypot(*(np.asarray(q, dtype=float)[:2] - clusters.xy[role]))) <= clusters.radii[role]
        if arrived and (mem.transit or not mem.settled):
            mem = mem._replace(settled=True, transit=False, since=step)
        mem = served(mem, r_g, fp)
        if mem.mode == M0 and mem.achieved >> mem.goal & 1:
            mem = mem._replace(mode=M2)
        if mem.settled and not mem.transit:
            mem = anchored(mem, q, near, clusters, step, fp)
        return mem
    edge = roles.edges[role - clusters.count]
    if mem.mode != M1 or mem.bridge != edge:
        mem = _anew(mem, mode=M1, goal=edge[0], bridge=edge, transit=mem.settled,
                    swing=pivot(mem, q, edge, clusters, fp, roles.edges))
    if (mem.transit or not mem.settled) and clusters.segment_distance(q, edge) <= fp.d:
        mem = mem._replace(settled=True, transit=False, since=step)
    if mem.swing is not None:
        a, u, _ = clusters.axis(edge)
        if float(np.linalg.norm(a + u * swing_place(mem.swing, edge, clusters, fp) - np.asarray(q)[:2])) <= fp.d:
            mem = mem._replace(swing=None)
    ends: tuple[float, ...] = ()
    if mem.settled and not mem.transit and mem.swing is None:
        chain = chain_of(q, edge, near.q, near.told, clusters, fp)
        mem = hushed(mem, chain, step, fp)
        mem = tally(mem, taut(mem, chain, fp), roles, fp)
        ends = tuple(float(x) for x in chain.ends) if chain.ends.below_hops or chain.ends.above_hops else ()
    return mem if mem.ends == ends else mem._replace(ends=ends)


def related(a: Told, b: Told) -> bool:
    """Whether two MAPs' roles belong together: one cluster's servers, or a relay and its edge's servers
    or fellow relays, neither on its way to a new role. Under the demand allocation only related MAPs
    attract and match velocities (control.flocking_terms): a MAP in transit flies at tens of m/s, and a relay
    that matched its velocity as it passed would be dragged off its chain."""
    if gossip_of(a).transit or gossip_of(b).transit:
        return False
    if a.mode == M1 and b.mode == M1:
        return a.bridge == b.bridge
    if a.mode == M1:
        return a.bridge is not None and b.goal in a.bridge
    if b.mode == M1:
        return b.bridge is not None and a.goal in b.bridge
    return a.goal == b.goal


def loose(a: Told, b: Told, fp: FlockParams) -> bool:
    """Rule 'loose': on a lagged vehicle a relay and the servers of its edge only repel. Behind the lag the
    bridge term is a velocity loop (envelope.capped) that eq. 10's pull and the standstill of a dozen servers
    outweigh: relays bound out along their edge stayed inside the cluster's lattice and the chain never
    spanned its gap (docs/vehicle.md). The chain rule alone places a relay; fellow relays still attract."""
    return envelope.limited(fp) and (a.mode == M1) != (b.mode == M1) and on('loose')


def inline(a: Told, b: Told, fp: FlockParams) -> bool:
    """Rule 'inline': on a lagged vehicle two fellow relays of one chain space themselves along their edge only.
    Eq. 10's lattice in the plane pushed relays closer than d along the edge to either side of its line, where
    E_c's pull did not hold them: a chain bunched near its cluster as a zig-zag stored sideways the MAPs it needed
    along its length, while its far end, taut, fell behind a drifting cluster (docs/notes/vehicle.md)."""
    return envelope.limited(fp) and a.mode == M1 and b.mode == M1 and on('inline')


def en_route(mem: Mine, q: np.ndarray, clusters: ClusterMap, fp: FlockParams) -> int:
    """The cluster a MAP in transit heads for first: the next one along the tree from the cluster it is at,
    or NO_GOAL to go straight to its role.

    A MAP in transit (demand allocation) left a place in a covered, connected formation because the clusters
    changed; flown straight to its new role it would cross empty ground out of everyone's range. Along the
    tree it passes clusters and relay chains. Roles never change while the clusters stand still, so then
    nothing is ever in transit.
    """
    if not on('tree') or not mem.transit or mem.goal == NO_GOAL or mem.swing is not None or mem.straight:
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


def leg_aim(q: np.ndarray, hop: int, clusters: ClusterMap, fp: FlockParams, achieved: int) -> np.ndarray:
    """Where a MAP in transit aims on its way to cluster hop: first the start of the relay chain from the
    cluster it is at, while it is short of it and more than d/2 off the chain's line; then hop's centre.

    Flown straight from its place in the disc, a MAP left the disc at its side and crossed 25-40 m off the
    chain, out of everyone's range (docs/notes/dynamics.md, "Leaving by the chain"). Towards a cluster not yet
    served (an arrival) there is no chain to join yet, and the detour only delayed the bridge: it flies
    straight."""
    aim_at = clusters.targets[hop]
    at = clusters.nearest(q, 0)
    if not on('chain') or at == NO_GOAL or at == hop or not (achieved >> at & 1 and achieved >> hop & 1):
        return aim_at
    edge = (min(at, hop), max(at, hop))
    a, u, length = clusters.axis(edge)
    if length <= 0:
        return aim_at
    if edge[0] != at:  # measured from the cluster it is at
        a, u = clusters.xy[at], -u
    xy = np.asarray(q, dtype=float)[:2]
    along = float(np.dot(xy - a, u))
    start = min(float(clusters.radii[at]), length / 2)
    off = abs(float(u[0] * (xy[1] - a[1]) - u[1] * (xy[0] - a[0])))
    if along < start and off > fp.d / 2:
        g = a + u * start
        return np.array([g[0], g[1], aim_at[2]])
    return aim_at


class Demand:
    """The demand allocation as an allocation (policies.Allocation)."""

    hearsay = True  # its chains and servers hold through a silent link by what a third MAP passes on

    def decide(self, mem: Memory, agent_id: int, n_users: int, r_g: float, q: np.ndarray, clusters: ClusterMap,
               fp: FlockParams, step: int = 0, near: Near = NOBODY) -> Memory:
        """Gossip first (the roles heard of, keys lost, roles short: vacancy.py) and the relays seen to fail
        (vacancy.vanished), then the role and mode."""
        heard = [gossip_of(t) for t in near.told]
        mine = gossip(Mine.of(mem), step, [g.seen for g in heard], [g.lost for g in heard], [g.short for g in heard])
        mine = vanished(mine, q, near, fp)
        return demand_switch(mine, agent_id, r_g, q, clusters, fp, step, near).memory()

    def reference(self, mem: Memory, agent_id: int, q: np.ndarray, nbr_q: np.ndarray, told: Sequence[Told],
                  clusters: ClusterMap, fp: FlockParams) -> Reference:
        """A MAP in transit aims at the next cluster along the tree; a relay bridges its own piece of the
        edge, where its chain needs it (eq. 13), moving with the edge."""
        mine = Mine.of(mem)
        here, v = aim(mine, q, clusters)
        hop = en_route(mine, q, clusters, fp)
        if hop != NO_GOAL:
            at, v = leg_aim(q, hop, clusters, fp, mine.achieved), clusters.velocities[hop]
            return Reference(at, at, at, M0, np.array([v, v, v]))
        if mine.mode == M1 and mine.bridge is not None:
            va, vb = clusters.velocities[mine.bridge[0]], clusters.velocities[mine.bridge[1]]
            place = swing_place(mine.swing, mine.bridge, clusters, fp) if mine.swing is not None else \
                mine.hold[0] if mine.hold is not None else \
                relay_place(agent_id, q, mine.bridge, nbr_q, told, clusters, fp, mine.lost, mine.short,
                            stay=mine.settled and not mine.transit and fp.hush > 0 and on('stay'), transit=mine.transit)
            q1, q2 = relay_slot(place, mine.bridge, clusters, fp)
            # The slot moves as its point of the edge does: at the velocity interpolated between the ends.
            length = clusters.axis(mine.bridge)[2]
            vs = va + (min(max(place / length, 0.0), 1.0) if length > 0 else 0.5) * (vb - va)
            return Reference(here, q1, q2, M1, np.array([v, vs, vs]))
        if mine.hold is not None and mine.goal != NO_GOAL:  # a server holding its place (anchored)
            here = here + np.array([*mine.hold, 0.0])
        return hold(mine, here, v)

    def link(self, a: Told, b: Told, fp: FlockParams) -> int:
        """Only related MAPs attract (control.flocking_terms), and on a lagged vehicle not a relay and a server
        (rule 'loose'), and fellow relays along their edge only (rule 'inline'); unrelated ones of which one is
        on its way to a new role pass each other at d/2 (docs/notes/dynamics.md, "Passing at d/2"), but not under the
        safety filter, whose separation rows turn such a pair aside late and hard: eq. 10's repulsion at d keeps them
        off those rows (docs/vehicle.md, "The filter without rule passing")."""
        if related(a, b):
            return APART if loose(a, b, fp) else INLINE if inline(a, b, fp) else RELATED
        passing = on('passing') and not (envelope.limited(fp) and fp.safety == 'filter')  # the filter flies it
        return PASSING if passing and (gossip_of(a).transit or gossip_of(b).transit) else APART

    def needed(self, own: Memory, other: Told) -> int:
        """A chain's links, both ends settled at their roles, once both the chain's clusters are served (in the own
        MAP's achieved goals): fellow relays of one edge keep theirs SHARED; a relay keeps its link to a server of its
        edge's clusters ALONE, and the server flies free of it (UNKEPT), since the server's place is where its users
        are and the relay's is wherever the chain needs it: a server held back by its chain left users unserved
        (docs/vehicle.md, "A relay keeps its link to a server alone"). A cluster's lattice holds itself together many
        times over; what splits a formation is a chain's last link giving way as its cluster drifts off, or a
        relay's (docs/notes/vehicle.md). A MAP not yet at its role keeps no link, so no link holds it back from where
        it is going; nor does a chain to a cluster not yet served, which is still being laid out as the MAPs fly in,
        and joins no users yet (docs/vehicle.md, "A chain's links once its clusters are served")."""
        a = Told.of(own)
        edge = a.bridge if a.mode == M1 else other.bridge
        if not (M1 in (a.mode, other.mode) and gossip_of(a).settled and gossip_of(other).settled and related(a, other)
                and (edge is None or all(own.achieved >> c & 1 for c in edge))):
            return UNKEPT
        return SHARED if a.mode == other.mode else ALONE if a.mode == M1 else UNKEPT
