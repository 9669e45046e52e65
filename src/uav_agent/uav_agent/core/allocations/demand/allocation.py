"""The demand allocation (`allocation: demand`, docs/allocation.md): every MAP takes one role from the start,
a cluster to serve or an edge of the MST over all clusters to relay on, by the share of [0, 1) its id's
key falls in, with shares sized by each role's demand in MAPs. Relays space themselves along their edge's
gap, swing about a shared cluster when the tree changes, and a MAP sent to a new role flies along the tree."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple, Optional, Sequence

import numpy as np

from ... import envelope
from ...clusters import NO_GOAL, ClusterMap, Edge
from ...state import APART, M0, M1, M2, NOBODY, PASSING, RELATED, Memory, Near, Reference, Told, aim, hold
from . import keys
from ...ablation import on
from .layout import Roles
from .memory import Mine, gossip_of
from .vacancy import code, gossip, role_of, vacate

if TYPE_CHECKING:
    from ...params import FlockParams

TAUT_STEPS = 100             # 10 s of a relay's chain found taut (demand.taut) find it one MAP short


def served(mem: Mine, r_g: float, fp: FlockParams) -> Mine:
    """The goal joins the achieved set once its coverage r_g passes r0 (Algorithm 2's test)."""
    if r_g > fp.r0 and not mem.achieved >> mem.goal & 1:
        mem = mem._replace(achieved=mem.achieved | 1 << mem.goal)
    return mem


def _anew(mem: Mine, **role: object) -> Mine:
    """A MAP's memory for a new role: what it knows of the clusters and the roles stays."""
    return Mine(achieved=mem.achieved, settled=mem.settled, seen=mem.seen, lost=mem.lost, short=mem.short,
                  since=mem.since, **role)  # type: ignore[arg-type]


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
    if role < clusters.count:
        if mem.goal != role or mem.mode == M1:
            old = mem.bridge if mem.mode == M1 else None
            straight = on('straight') and old is not None and role in old and old not in roles.edges and clusters.ends_live(old)
            mem = _anew(mem, mode=M0, goal=role, transit=mem.settled, straight=straight)
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
        mem = _anew(mem, mode=M1, goal=edge[0], bridge=edge, transit=mem.settled, swing=pivot(mem, q, edge, clusters, fp))
    if (mem.transit or not mem.settled) and clusters.segment_distance(q, edge) <= fp.d:
        mem = mem._replace(settled=True, transit=False, since=step)
    if mem.swing is not None:
        a, u, _ = clusters.axis(edge)
        if float(np.linalg.norm(a + u * swing_place(mem.swing, edge, clusters, fp) - np.asarray(q)[:2])) <= fp.d:
            mem = mem._replace(swing=None)
    if mem.settled and not mem.transit and mem.swing is None:
        chain = _chain(q, edge, near.q, near.told, clusters, fp)
        mem = hushed(mem, chain, step, fp)
        mem = tally(mem, taut(mem, chain, fp), roles)
    return mem


class Chain(NamedTuple):
    """A relay's chain as it hears it, in m along the edge from its first centre: where the relay is, the
    nearest member heard below it and above it (±inf: that side silent), and how far those two lie off the
    edge's line."""

    here: float
    below: float
    above: float
    below_aside: float = 0.0
    above_aside: float = 0.0


def hushed(mem: Mine, chain: Chain, step: int, fp: FlockParams) -> Mine:
    """Whether a relay that hears one side of its chain no more holds its place (Mine.hold: its place along
    the edge).

    Under a channel that loses states, a silent side is most often a neighbour whose states are lost, not an
    empty side: a relay that heard a member on both sides within fp.hush steps holds where it was when the
    side fell silent, instead of reaching r - 1 m beyond the other side (relay_place). Reaching, it would pull
    its chain towards the silent side, and the chain crawls until it breaks on the other (docs/links.md).
    """
    return _hushed(mem, math.isfinite(chain.below) and math.isfinite(chain.above), (chain.here,), step, fp)


def anchored(mem: Mine, q: np.ndarray, near: Near, clusters: ClusterMap, step: int, fp: FlockParams) -> Mine:
    """Whether a server that hears no relay of its cluster's edges any more holds its place (Mine.hold: its
    offset from the cluster's centre): the relay's pull held it out at the end of the chain, and without it
    the server would fall back into its cluster and break the link the silence did not (docs/links.md)."""
    if fp.hush <= 0 or not on('hold'):
        return mem  # as _hushed would, before looking at the neighbours
    relays = any(t.mode == M1 and t.bridge is not None and mem.goal in t.bridge and not gossip_of(t).transit
                 for t in near.told)
    offset = tuple(float(x) for x in np.asarray(q, dtype=float)[:2] - clusters.xy[mem.goal])
    return _hushed(mem, relays, offset, step, fp)


def _hushed(mem: Mine, whole: bool, place: tuple[float, ...], step: int, fp: FlockParams) -> Mine:
    """Rule 'hold': a MAP whose links were whole within fp.hush steps (0 under the paper's channel, where
    silence is absence) holds `place` from the step they were not."""
    if fp.hush <= 0 or not on('hold'):
        return mem
    if whole:
        return mem if mem.whole == step and mem.hold is None else mem._replace(whole=step, hold=None)
    if mem.whole >= 0 and step - mem.whole <= fp.hush:
        return mem if mem.hold is not None else mem._replace(hold=place)
    return mem if mem.hold is None else mem._replace(hold=None)


def _gap_from(end: int, edge: Edge, clusters: ClusterMap, fp: FlockParams) -> tuple[float, float, float]:
    """(edge length, start, end of its gap), in m from the centre of its cluster `end`."""
    start, stop = clusters.gap(edge, fp.d / 2)
    length = clusters.axis(edge)[2]
    return (length, start, stop) if edge[0] == end else (length, length - stop, length - start)


def pivot(mem: Mine, q: np.ndarray, edge: Edge, clusters: ClusterMap, fp: FlockParams) -> Optional[tuple[int, float]]:
    """The swing a relay takes to edge: the cluster its old edge shares with it, and the relay's place along
    the old gap from that cluster (0..1); None if it was not settled on an edge that shares exactly one.

    When a drifting cluster changes the tree, relays of an edge that left it take the keys of one that joined.
    Keeping its place from the shared cluster P and flying straight there, each relay lands on the new edge
    about where the chain needs it, and those near P barely move: the new chain forms along its whole length
    at once, where flying along the tree (through P's centre and out) would grow it from one end, one relay
    at a time (docs/dynamics.md, "Swinging chains").
    """
    old = mem.bridge
    if not on('swing') or mem.mode != M1 or old is None or not mem.settled or not clusters.ends_live(old):
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


def relay_place(agent_id: int, q: np.ndarray, edge: Edge, nbr_q: np.ndarray, told: Sequence[Told],
                clusters: ClusterMap, fp: FlockParams, lost: tuple[keys.Span, ...] = (),
                short: tuple[tuple[int, int], ...] = (), stay: bool = False) -> float:
    """Where along its edge a relay aims (m from the first cluster's centre): midway along its chain.

    The chain of an edge (a, b) is its relays and the servers of a and b. Servers of a lie on the a side
    of every relay and servers of b on the b side, so the outermost server heard is each side's anchor.
    A relay that hears a chain member on each side aims midway between the nearest two, so the chain
    relaxes to even spacing between the clusters' outermost servers wherever they are; with one side
    silent it reaches r - 1 m beyond the other towards the silent side (a chain short of relays still spans
    its gap if r per link does); hearing none, it takes its own place in the gap by its key, unless it
    should `stay` (rule 'stay': a settled relay under a lossy channel, whose chain is most likely there
    unheard; flying to its place by key it left a gap behind it, docs/links.md).
    """
    here, below, above, below_aside, above_aside = _chain(q, edge, nbr_q, told, clusters, fp)
    length = clusters.axis(edge)[2]
    if math.isfinite(below) and math.isfinite(above):
        return (below + above) / 2.0
    if math.isfinite(below):
        return min(_reach_past(below, below_aside, +1, fp), length)
    if math.isfinite(above):
        return max(_reach_past(above, above_aside, -1, fp), 0.0)
    if stay:
        return here
    roles, key = role_of(agent_id, lost, clusters, fp, short)
    start, stop = clusters.gap(edge, fp.d / 2)
    at = roles.place(key, clusters.count + roles.edges.index(edge))
    return start + at * (stop - start)


def _chain(q: np.ndarray, edge: Edge, nbr_q: np.ndarray, told: Sequence[Told], clusters: ClusterMap,
           fp: FlockParams) -> Chain:
    a, u, length = clusters.axis(edge)
    here = float(np.dot(np.asarray(q, dtype=float)[:2] - a, u))
    below, above = -math.inf, math.inf
    below_q = above_q = None
    for qj, tj in zip(nbr_q, told):
        if not _in_place(qj, tj, edge, clusters, fp):
            continue
        at = float(np.dot(qj[:2] - a, u))
        if tj.mode != M1 and tj.goal == edge[0] or tj.mode == M1 and tj.bridge == edge and at < here:
            if at > below:
                below, below_q = at, qj
        elif tj.mode != M1 and tj.goal == edge[1] or tj.mode == M1 and tj.bridge == edge and at > here:
            if at < above:
                above, above_q = at, qj

    def aside(qj: Optional[np.ndarray]) -> float:
        return 0.0 if qj is None else abs(float(u[0] * (qj[1] - a[1]) - u[1] * (qj[0] - a[0])))
    return Chain(here, below, above, aside(below_q), aside(above_q))


def _reach_past(at: float, aside: float, away: int, fp: FlockParams) -> float:
    """Where a relay reaching past the last member it hears on one side aims: that member `at` m along the
    edge and `aside` m off its line, the relay `away` (+1: farther along, -1: back) from it. r - 1 m in the
    plane (rule 'offset'): measured along the line alone, the reach from a server at the side of its disc put
    the relay out of its range (docs/dynamics.md, "Reaching in the plane"). Under the paper's channel only:
    under bursts of loss it cost drifting runs 1.25 points."""
    if on('offset') and fp.hush <= 0:
        reach = reach_of(fp) - 1.0
        return at + away * math.sqrt(max(reach * reach - aside * aside, 0.0))
    # Summed in this order, as before the rule: runs under a lossy channel stay byte for byte what they were.
    return at + reach_of(fp) - 1.0 if away > 0 else at - reach_of(fp) + 1.0


def taut(mem: Mine, chain: Chain, fp: FlockParams) -> bool:
    """Whether a settled relay's chain (_chain) is stretched past what holds: the members it hears on either
    side are more than d + r apart (links longer than (d + r) / 2 break as the MAPs sway), or one side is
    silent though its cluster was heard of since the relay settled (the chain was whole and no longer reaches)
    and the relay does not take the silence for lost states (hushed)."""
    assert mem.bridge is not None
    below, above = chain.below, chain.above
    if math.isfinite(below) and math.isfinite(above):
        return above - below > fp.d + reach_of(fp)
    if math.isfinite(below) == math.isfinite(above) or mem.hold is not None:
        return False  # hears no member (cut off alone, nothing to say of the chain), or holds through a silence
    silent = mem.bridge[1] if math.isfinite(below) else mem.bridge[0]
    return dict(mem.seen).get(silent, -1) > mem.since


def tally(mem: Mine, taut_now: bool, roles: Roles) -> Mine:
    """Count the steps a relay has found its chain taut since it took its role; each TAUT_STEPS of them find
    the chain one MAP short (up to its demand, rounded up), told to all by gossip (Memory.short, merged by
    the larger count), so every MAP grows the edge's share alike (vacancy.view)."""
    if not taut_now or not on('short'):
        return mem
    assert mem.bridge is not None
    steps = mem.taut + 1
    found = min(steps // TAUT_STEPS, math.ceil(roles.demand[roles.index(mem.bridge)]))
    short = dict(mem.short)
    if found > short.get(code(mem.bridge), 0):
        short[code(mem.bridge)] = found
        return mem._replace(taut=steps, short=tuple(sorted(short.items())))
    return mem._replace(taut=steps)


def reach_of(fp: FlockParams) -> float:
    """The longest link a chain is laid on (m): r, or under a channel that loses long links the distance it
    still delivers half of what is sent over (FlockParams.reach; rule 'inside')."""
    return fp.link_reach if on('inside') else fp.r


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
    chain, out of everyone's range (docs/dynamics.md, "Leaving by the chain"). Towards a cluster not yet
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
        """Gossip first (the roles heard of, keys lost, roles short: vacancy.py), then the role and mode."""
        heard = [gossip_of(t) for t in near.told]
        mine = gossip(Mine.of(mem), step, [g.seen for g in heard], [g.lost for g in heard], [g.short for g in heard])
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
                            stay=mine.settled and not mine.transit and fp.hush > 0 and on('stay'))
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
        (rule 'loose'); unrelated ones of which one is on its way to a new role pass each other at d/2
        (docs/dynamics.md, "Passing at d/2")."""
        if related(a, b):
            return APART if loose(a, b, fp) else RELATED
        return PASSING if (gossip_of(a).transit or gossip_of(b).transit) and on('passing') else APART
