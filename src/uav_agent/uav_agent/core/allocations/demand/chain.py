"""The demand allocation's relay chains (docs/allocation.md): where a relay places itself along its edge's
gap among the members it hears (relay_place), how a chain swings about a shared cluster (pivot), when a chain
is taut and short of MAPs (taut, tally), and how a relay that hears too little of its chain holds its place
under a lossy channel (hushed, anchored)."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple, Optional, Sequence

import numpy as np

from ... import envelope
from ...ablation import on
from ...clusters import ClusterMap, Edge
from ...state import M1, Near, Told
from . import keys
from .layout import Roles
from .memory import Mine, gossip_of
from .vacancy import PATIENT_STEPS, code, patient, role_of

if TYPE_CHECKING:
    from ...params import FlockParams

TAUT_STEPS = 100             # 10 s of a relay's chain found taut (demand.taut) find it one MAP short
ENDS_HOPS = 64               # rule 'ends': a count of hops past this is a stale loop, not a chain


class Ends(NamedTuple):
    """Rule 'ends': how far a relay's chain reaches on each side as its members pass it on, hop by hop: the
    links from the relay to the anchor (the outermost server heard of that side's cluster; 0: not known) and
    where that anchor is, in m along the edge, as a point on its line (the reach from it in the plane; 0 when
    not known, so a message never carries a NaN)."""

    below_hops: int = 0
    below_at: float = 0.0
    above_hops: int = 0
    above_at: float = 0.0


class Chain(NamedTuple):
    """A relay's chain as it hears it, in m along the edge from its first centre: where the relay is, the
    nearest member heard below it and above it (±inf: that side silent), how far those two lie off the
    edge's line, and its ends as they pass them on (rule 'ends')."""

    here: float
    below: float
    above: float
    below_aside: float = 0.0
    above_aside: float = 0.0
    ends: Ends = Ends()


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


def pivot(mem: Mine, q: np.ndarray, edge: Edge, clusters: ClusterMap, fp: FlockParams,
          edges: Sequence[Edge] = ()) -> Optional[tuple[int, float]]:
    """The swing a relay takes to edge: the cluster its old edge shares with it, and the relay's place along
    the old gap from that cluster (0..1); None if it was not settled on an edge that shares exactly one, or, on a
    lagged vehicle, if its old edge is still one of the roles' edges (the tree did not swap it).

    When a drifting cluster changes the tree, relays of an edge that left it take the keys of one that joined.
    Keeping its place from the shared cluster P and flying straight there, each relay lands on the new edge
    about where the chain needs it, and those near P barely move: the new chain forms along its whole length
    at once, where flying along the tree (through P's centre and out) would grow it from one end, one relay
    at a time (docs/dynamics.md, "Swinging chains"). A relay that one chain still standing gives up to another
    (a drifting edge growing, its neighbour's share shrinking) swings alone: on a lagged vehicle it flew the chord,
    100-200 m, out of everyone's range for 7-15 s (drifting layout 3, seed 0), so it flies the tree, along its
    old chain, through the cluster and out along the new one (docs/notes/vehicle.md).
    """
    old = mem.bridge
    if not on('swing') or mem.mode != M1 or old is None or not mem.settled or not clusters.ends_live(old):
        return None
    if envelope.limited(fp) and old in edges:
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
                short: tuple[tuple[int, int], ...] = (), stay: bool = False, transit: bool = False) -> float:
    """Where along its edge a relay aims (m from the first cluster's centre): midway along its chain.

    The chain of an edge (a, b) is its relays and the servers of a and b. Servers of a lie on the a side
    of every relay and servers of b on the b side, so the outermost server heard is each side's anchor.
    A relay that hears a chain member on each side aims midway between the nearest two, so the chain
    relaxes to even spacing between the clusters' outermost servers wherever they are; with one side
    silent it reaches r - 1 m beyond the other towards the silent side (a chain short of relays still spans
    its gap if r per link does); hearing none, it takes its own place in the gap by its key, unless it
    should `stay` (rule 'stay': a settled relay under a lossy channel, whose chain is most likely there
    unheard; flying to its place by key it left a gap behind it, docs/links.md), or it is in `transit` to a
    new chain on a lagged vehicle (rule 'ends'): then it joins the gap at its nearer end, among the anchor's
    servers, and the chain grows from there. By its key it was sent into the middle of an empty gap, alone
    for seconds at 10-15 m/s while the chain was laid (docs/notes/vehicle.md, "A new chain grown from its
    anchor").
    """
    chain = chain_of(q, edge, nbr_q, told, clusters, fp)
    here, below, above, below_aside, above_aside = chain[:5]
    length = clusters.axis(edge)[2]
    spread = ends_place(chain.ends, length, fp)
    if spread is not None:
        return spread
    if math.isfinite(below) and math.isfinite(above):
        return (below + above) / 2.0
    if math.isfinite(below):
        return min(_reach_past(below, below_aside, +1, fp), length)
    if math.isfinite(above):
        return max(_reach_past(above, above_aside, -1, fp), 0.0)
    if stay:
        return here
    start, stop = clusters.gap(edge, fp.d / 2)
    if transit and spreads(fp):
        return start if abs(here - start) <= abs(here - stop) else stop
    roles, key = role_of(agent_id, lost, clusters, fp, short)
    at = roles.place(key, clusters.count + roles.edges.index(edge))
    return start + at * (stop - start)


def chain_of(q: np.ndarray, edge: Edge, nbr_q: np.ndarray, told: Sequence[Told], clusters: ClusterMap,
           fp: FlockParams) -> Chain:
    a, u, length = clusters.axis(edge)
    here = float(np.dot(np.asarray(q, dtype=float)[:2] - a, u))
    below, above = -math.inf, math.inf
    below_q = above_q = below_t = above_t = None
    for qj, tj in zip(nbr_q, told):
        if not _in_place(qj, tj, edge, clusters, fp):
            continue
        at = float(np.dot(qj[:2] - a, u))
        if tj.mode != M1 and tj.goal == edge[0] or tj.mode == M1 and tj.bridge == edge and at < here:
            if at > below:
                below, below_q, below_t = at, qj, tj
        elif tj.mode != M1 and tj.goal == edge[1] or tj.mode == M1 and tj.bridge == edge and at > here:
            if at < above:
                above, above_q, above_t = at, qj, tj

    def aside(qj: Optional[np.ndarray]) -> float:
        return 0.0 if qj is None else abs(float(u[0] * (qj[1] - a[1]) - u[1] * (qj[0] - a[0])))
    chain = Chain(here, below, above, aside(below_q), aside(above_q))
    if not spreads(fp):
        return chain
    hb, eb = _end(below, chain.below_aside, below_t, +1, fp)
    ha, ea = _end(above, chain.above_aside, above_t, -1, fp)
    return chain._replace(ends=Ends(hb, eb, ha, ea))


def spreads(fp: FlockParams) -> bool:
    """Whether rule 'ends' acts: on a lagged vehicle under the paper's channel (a lossy one holds places through
    silences instead: rule 'hold')."""
    return envelope.limited(fp) and fp.hush <= 0 and on('ends')


def _end(at: float, aside: float, told: Optional[Told], away: int, fp: FlockParams) -> tuple[int, float]:
    """One side's end of a relay's chain from the nearest member heard on it (away: +1 below, -1 above): a server
    is the anchor, one hop off; a relay passes on its own count and anchor on that side, one hop more."""
    if told is None:
        return 0, 0.0
    if told.mode != M1:  # the anchor, as a point on the line: its reach in the plane less one link along it
        return 1, _reach_past(at, aside, away, fp) - away * (reach_of(fp) - 1.0)
    ends = gossip_of(told).ends
    if len(ends) != 4:
        return 0, 0.0
    hops, end = (ends[0], ends[1]) if away > 0 else (ends[2], ends[3])
    if not 0 < hops < ENDS_HOPS:
        return 0, 0.0
    return int(hops) + 1, float(end)


def ends_place(ends: Ends, length: float, fp: FlockParams) -> Optional[float]:
    """Rule 'ends': where along its edge (m) a relay aims that knows its rank in its chain, or None.

    Each relay aiming midway between the members it hears, a chain's slack travels to its far end as a diffusion,
    in a time that grows with the square of its length: a chain of a dozen relays fell behind a cluster drifting
    at 2 m/s and broke at its far end with its relays bunched near the other (docs/notes/vehicle.md). Knowing
    both anchors and its rank, a relay flies to its even share of the span at once; a chain too short for its
    span (and one that knows one anchor only) is laid out taut from an anchor at a link of r - 1 m, from the
    first cluster's when both are known, so every relay of it picks the same one.
    """
    reach = reach_of(fp) - 1.0
    hb, eb, ha, ea = ends
    if hb and ha and (ea - eb) <= (hb + ha) * reach:
        return eb + hb * (ea - eb) / (hb + ha)
    if hb:
        return min(eb + hb * reach, length)
    if ha:
        return max(ea - ha * reach, 0.0)
    return None


def _reach_past(at: float, aside: float, away: int, fp: FlockParams) -> float:
    """Where a relay reaching past the last member it hears on one side aims: that member `at` m along the
    edge and `aside` m off its line, the relay `away` (+1: farther along, -1: back) from it. r - 1 m in the
    plane (rule 'offset'): measured along the line alone, the reach from a server at the side of its disc put
    the relay out of its range (docs/notes/dynamics.md, "Reaching in the plane"). Under the paper's channel only:
    under bursts of loss it cost drifting runs 1.25 points."""
    if on('offset') and fp.hush <= 0:
        reach = reach_of(fp) - 1.0
        return at + away * math.sqrt(max(reach * reach - aside * aside, 0.0))
    # Summed in this order, as before the rule: runs under a lossy channel stay byte for byte what they were.
    return at + reach_of(fp) - 1.0 if away > 0 else at - reach_of(fp) + 1.0


def taut(mem: Mine, chain: Chain, fp: FlockParams) -> bool:
    """Whether a settled relay's chain (chain_of) is stretched past what holds: the members it hears on either
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


def tally(mem: Mine, taut_now: bool, roles: Roles, fp: FlockParams) -> Mine:
    """Count the steps a relay has found its chain taut since it took its role; each taut_steps of them find
    the chain one MAP short (up to its demand, rounded up), told to all by gossip (Memory.short, merged by
    the larger count), so every MAP grows the edge's share alike (vacancy.view)."""
    if not taut_now or not on('short'):
        return mem
    assert mem.bridge is not None
    steps = mem.taut + 1
    found = min(steps // taut_steps(fp), math.ceil(roles.demand[roles.index(mem.bridge)]))
    short = dict(mem.short)
    if found > short.get(code(mem.bridge), 0):
        short[code(mem.bridge)] = found
        return mem._replace(taut=steps, short=tuple(sorted(short.items())))
    return mem._replace(taut=steps)


def taut_steps(fp: FlockParams) -> int:
    """Steps of a taut chain that find it one MAP short: TAUT_STEPS, or on a lagged vehicle PATIENT_STEPS (rule
    'patient', as for a role's keys declared lost). Behind a multirotor's envelope a chain is found taut, one
    side silent, while its relays are still flying in, and every MAP asked for crosses the formation: found
    short after 10 s, still layouts were connected 91.2 % of the time after convergence, after 30 s 96.1 %, at
    a cost after a loss (80.1 % to 73.4 %; docs/notes/vehicle.md)."""
    return PATIENT_STEPS if patient(fp) else TAUT_STEPS


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
