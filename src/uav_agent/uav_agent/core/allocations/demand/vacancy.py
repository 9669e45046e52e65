"""Roles emptied by failures, noticed and re-staffed with no count of MAPs (docs/notes/dynamics.md, "Vacated roles").

Under the demand allocation a role is the set of keys in its pieces of [0, 1). MAPs that fail keep their
keys, so a role whose MAPs all failed keeps its share and nobody takes it: a cluster stays uncovered, or
the tree stays cut, for good. Two gossiped values close that gap, each merged like the achieved goals:
- per role, the last step a member was heard of (a MAP states its own role now; merge: the larger step);
- the spans of keys known lost (merge: union).
A MAP at a role's place (its cluster's disc, or along its edge) that has heard of no member for
VACANT_STEPS, while its component hears of most roles, declares that role's keys lost. Every MAP then
squeezes the lost spans out of the key line (keys.squeeze): the survivors' keys cover [0, 1) again, and the
emptied role takes its share back from its neighbours on the line and the others' surplus (keys.carry).
A role can also be left short rather than empty: a chain with too few relays left to span its gap. Its
relays find it so (demand.taut, demand.tally) and gossip how many MAPs it lacks (merge: the larger count);
every MAP grows that role's share by as many MAPs' worth before laying the roles over the keys (view), so
the chain takes them from its neighbours on the line.
A message carries O(roles) numbers, never O(MAPs).
"""
from __future__ import annotations

import math
from functools import lru_cache
from typing import TYPE_CHECKING, Iterable, Optional, Sequence

import numpy as np

from ... import envelope
from ...clusters import NO_GOAL, ClusterMap, key_of
from ...state import M1, Near, Told
from . import keys
from ...ablation import on
from . import layout
from .layout import Roles
from .memory import Mine

if TYPE_CHECKING:
    from ...params import FlockParams

VACANT_STEPS = 100  # 10 s at Δt = 0.1 s: longer than the outages of a formation that merely moves
PATIENT_STEPS = 300  # 30 s on a lagged vehicle (rule 'patient'): a multirotor's MAPs take 10-20 s to cross to a
                     # role, and a chain's relays reach its ends one by one

STEP_S = 0.1  # a step (s): the steps above count at this Δt
# A relay seen to fail (vanished, rule 'patient'): one heard this far inside r cannot leave r by the next step (two
# MAPs open at most 2 v_max Δt, 3 m at 15 m/s, and their own GNSS errors, σ 0.5 m each, differ by well under 2 m), and
# one heard again is within v_max Δt of where it was (its GNSS error drifts over a minute; separation keeps others
# 3 m off).
VANISH_MARGIN_S = 2 * STEP_S   # times v_max, plus VANISH_GNSS
VANISH_GNSS = 2.0              # m
VANISH_MATCH_S = STEP_S        # times v_max, plus VANISH_MATCH_GNSS
VANISH_MATCH_GNSS = 0.5        # m

EDGE_CODE = 64      # role codes: cluster k is k (< 63 ids a run may use), edge (a, b) is 64 + 64 a + b


def nearest(fp: FlockParams) -> bool:
    """Rule 'nearest': whether a new role's share is lent first by the clusters nearest it on the tree (layout.roles),
    not by those most above their share wherever they are: on a lagged vehicle, MAPs cross to it from nearby."""
    return envelope.limited(fp) and on('nearest')


def vacant_steps(fp: FlockParams) -> int:
    """Steps a role goes unheard of before it is declared lost: VACANT_STEPS, or PATIENT_STEPS on a lagged vehicle
    (rule 'patient'). Behind a multirotor's envelope the relays of a long edge arrive one by one over 10-20 s, and
    a server at the edge's end that had heard of them through gossip declared their keys lost while they flew in:
    squeezed out of the key line, the lost keys moved every MAP's key and sent a dozen MAPs across the formation
    in a still layout (docs/notes/vehicle.md)."""
    return PATIENT_STEPS if patient(fp) else VACANT_STEPS


def patient(fp: FlockParams) -> bool:
    """Whether rule 'patient' acts: on a lagged vehicle, whose MAPs take PATIENT_STEPS to fly in, neither a role's
    keys are declared lost (vacant_steps) nor a chain found short (chain.taut_steps) sooner."""
    return envelope.limited(fp) and on('patient')


def watching(fp: FlockParams) -> bool:
    """Whether a MAP looks for relays that failed (vanished): under rule 'patient', and under the paper's channel only,
    where a neighbour within r is heard at every step (under a lossy one, silence is most often lost states)."""
    return patient(fp) and fp.hush <= 0


def vanished(mem: Mine, q: np.ndarray, near: Near, fp: FlockParams) -> Mine:
    """Rule 'patient', a relay seen to fail: a relay heard at the last step well within r, and heard nowhere near
    where it was now, has failed, and its chain is found one MAP short at once, one per such relay (Mine.short, merged
    by the larger count: two MAPs that saw one failure ask for one MAP, not two).

    Patience waits out a silence because a silent role may still be on its way (vacant_steps, chain.taut_steps). A
    relay that vanishes from well within range is no such silence: nothing flies out of range in one step. Waiting
    30 s per MAP to find a broken chain short, still layouts after a loss of 30 % stayed split for the rest of the
    run in 3 runs of 60 (docs/notes/vehicle.md, "A relay seen to fail")."""
    if not watching(fp):
        return mem
    now = np.asarray(near.q, dtype=float)[:, :2] if len(near.told) else np.zeros((0, 2))
    gone: dict[int, int] = {}
    if mem.around:
        was = np.asarray(mem.around, dtype=float)
        match = fp.v_max * VANISH_MATCH_S + VANISH_MATCH_GNSS
        if len(now):
            seen = (np.hypot(was[:, None, 0] - now[None, :, 0], was[:, None, 1] - now[None, :, 1]) <= match).any(axis=1)
        else:
            seen = np.zeros(len(was), dtype=bool)
        for c in was[~seen, 2].astype(int).tolist():
            gone[c] = gone.get(c, 0) + 1
    within = fp.r - fp.v_max * VANISH_MARGIN_S - VANISH_GNSS
    xy = np.asarray(q, dtype=float)[:2]
    relays = [i for i, t in enumerate(near.told) if t.mode == M1 and t.bridge is not None]
    around: tuple[tuple[float, float, int], ...] = ()
    if relays:
        at = now[relays]
        close = np.hypot(at[:, 0] - xy[0], at[:, 1] - xy[1]) <= within
        around = tuple((float(x), float(y), stated_role(near.told[i]))  # type: ignore[misc]
                       for (x, y), i, ok in zip(at.tolist(), relays, close.tolist()) if ok)
    if not gone:
        return mem if around == mem.around else mem._replace(around=around)
    short = dict(mem.short)
    for c, n in gone.items():
        short[c] = short.get(c, 0) + n
    return mem._replace(around=around, short=tuple(sorted(short.items())))


def code(role: keys.RoleId) -> int:
    return role if isinstance(role, int) else EDGE_CODE + EDGE_CODE * role[0] + role[1]


def stated_role(t: Told) -> Optional[int]:
    """The code of the role a MAP states (a relay's edge, a server's cluster), None before it has one."""
    if t.mode == M1 and t.bridge is not None:
        return code(t.bridge)
    return None if t.goal == NO_GOAL else t.goal


Seen = Sequence[tuple[int, int]]  # (role code, last step a member was heard of), as a state message carries it
Short = Sequence[tuple[int, int]]  # (role code, MAPs it was found short of)
# What the neighbours' state messages said: each one's roles heard of, lost spans, and roles found short.
Heard = tuple[Sequence[Seen], Sequence[Sequence[keys.Span]], Sequence[Short]]


def _latest(mine: Iterable[tuple[int, int]], heard: Iterable[Iterable[tuple[int, int]]]) -> dict[int, int]:
    """(role code, value) pairs merged by the larger value: the one merge of the step heard and the count."""
    out = dict(mine)
    get = out.get  # the loop below is the allocation's hottest with a thousand MAPs (bench_sim, the city)
    for told in heard:
        for c, k in told:
            if k > get(c, -1):
                out[c] = k
    return out


def gossip(mem: Mine, step: int, heard_seen: Iterable[Seen], heard_lost: Iterable[Sequence[keys.Span]],
           heard_short: Iterable[Short] = ()) -> Mine:
    """Merge what the neighbours told of roles, lost keys and short roles, and state this MAP's own role as
    heard now."""
    seen = _latest(mem.seen, heard_seen)
    own = stated_role(Told(mem.mode, mem.goal, mem.bridge))
    if own is not None:
        seen[own] = step
    lost = keys.united(mem.lost, *heard_lost)
    short = tuple(sorted(_latest(mem.short, heard_short).items()))
    return mem._replace(seen=tuple(sorted(seen.items())), lost=lost, short=short)


def view(roles: Roles, lost: tuple[keys.Span, ...], short: tuple[tuple[int, int], ...] = (),
         near: bool = False) -> Roles:
    """The roles with the lost keys squeezed out and the short roles' shares grown: each role's share laid
    over the survivors' keys. near: what a short edge grows by is lent by its own two clusters (rule 'nearest')."""
    if not (lost or short) or sum(roles.share) <= 0:
        return roles  # no hashing on the usual path
    return _squeezed_view(roles, lost, short, near)


def role_of(agent_id: int, lost: tuple[keys.Span, ...], clusters: ClusterMap, fp: FlockParams,
            short: tuple[tuple[int, int], ...] = ()) -> tuple[Roles, float]:
    """The roles as this MAP lays them out, and where its key lies among the survivors' keys."""
    near = nearest(fp)
    return view(layout.roles(clusters, fp.d, near), lost, short, near), keys.squeeze(key_of(agent_id), lost)


@lru_cache(maxsize=256)
def _squeezed_view(roles: Roles, lost: tuple[keys.Span, ...], short: tuple[tuple[int, int], ...],
                   near: bool) -> Roles:
    share = _grown(roles, short, near) if short else roles.share
    pieces = keys.carry(keys.squeezed(roles.pieces, lost), dict(zip(roles.ids, share)))
    return roles._replace(share=share, pieces=pieces)


def _grown(roles: Roles, short: tuple[tuple[int, int], ...], near: bool) -> tuple[float, ...]:
    """The shares with each role found short of n MAPs (demand.tally, vanished) grown by n MAPs' worth of the
    demand: taken from every role alike, or under rule 'nearest' lent by the short edge's own two clusters, down to
    half what they hold (the rest from every role alike). Taken alike, the MAPs a broken chain asked for were
    whichever keys the growth reached, anywhere in the formation, and each crossed it (docs/notes/vehicle.md)."""
    ids, share = roles.ids, roles.share
    extra = dict(short)
    total = sum(roles.demand)
    weights = [s * total + (extra.get(code(r), 0) if s > 0 else 0) for r, s in zip(ids, share)]
    whole = sum(weights)
    alike = tuple(w / whole for w in weights)
    if not near:
        return alike
    out = list(share)
    for i, r in enumerate(ids):
        if isinstance(r, int) or alike[i] <= share[i]:
            continue
        want = alike[i] - share[i]
        ends = [roles.index(c) for c in r]
        held = sum(out[j] for j in ends)
        lent = min(want, held / 2.0)
        for j in ends:
            out[j] -= lent * out[j] / held if held > 0 else 0.0
        out[i] += lent
        rest = want - lent
        if rest > 0:
            others = sum(o for k, o in enumerate(out) if k != i)
            out = [o + rest if k == i else o * (1.0 - rest / others) for k, o in enumerate(out)]
    return tuple(out)


def vacate(mem: Mine, step: int, q: np.ndarray, clusters: ClusterMap, fp: FlockParams) -> Mine:
    """Declare lost the keys of each role this MAP is at and has heard no member of for VACANT_STEPS.

    Only a role heard of since this MAP last reached its place can be declared: one whose MAPs are still on
    their way (the formation forming, or a tree that changed) was never there to be lost. Only a MAP whose
    component hears of two roles or more, and of at least a third of all, declares: a MAP cut off alone, or
    a small piece of the formation split off, never takes the rest for lost; nor does a MAP in transit. A
    declared role counts as heard VACANT_STEPS from now, so its new members, who may fly in from a part of the
    formation not yet joined to this one, have twice that to arrive before it can be declared again.
    """
    near = nearest(fp)
    roles = view(layout.roles(clusters, fp.d, near), mem.lost, mem.short, near)
    current, codes = _current(roles)
    seen = {c: k for c, k in mem.seen if c in codes}  # roles that left the layout are forgotten
    short = tuple((c, n) for c, n in mem.short if c in codes)
    vacant = vacant_steps(fp)
    stale = [r for r, c in current if step - seen.get(c, -math.inf) > vacant]
    lost = mem.lost
    fresh = len(current) - len(stale)
    if on('vacate') and mem.since >= 0 and not mem.transit and stale and fresh >= 2 and len(stale) <= 2 * fresh:
        for r in stale:
            if seen.get(code(r), -1) > mem.since and _at(q, r, clusters, fp):
                mine = [(keys.expand(lo, lost), keys.expand(hi, lost)) for lo, hi, role in roles.pieces if role == r]
                lost = keys.united(lost, mine)
                seen[code(r)] = step + vacant
    new = tuple(sorted(seen.items()))
    if new == mem.seen and lost == mem.lost and short == mem.short:
        return mem
    return mem._replace(seen=new, lost=lost, short=short)


@lru_cache(maxsize=64)
def _current(roles: Roles) -> tuple[tuple[tuple[keys.RoleId, int], ...], frozenset[int]]:
    """The roles with a share, each with its code, and those codes: the same for every MAP that laid out the
    same roles, so worked out once for all of them."""
    current = tuple((r, code(r)) for r, share in zip(roles.ids, roles.share) if share > 0)
    return current, frozenset(c for _, c in current)


def _at(q: np.ndarray, role: keys.RoleId, clusters: ClusterMap, fp: FlockParams) -> bool:
    """Whether a MAP at q would hear the role's members, were they in place: inside its cluster's disc (the
    servers spread over it), or within d of an end of its edge's gap (a chain's end relay stays in reach of
    the outermost servers there). A MAP that merely sees the role's place from afar proves nothing."""
    xy = np.asarray(q, dtype=float)[:2]
    if isinstance(role, int):
        return float(np.hypot(*(xy - clusters.xy[role]))) <= clusters.radii[role]
    a, u, _ = clusters.axis(role)
    start, stop = clusters.gap(role, fp.d / 2)
    return min(float(np.linalg.norm(a + u * at - xy)) for at in (start, stop)) <= fp.d
