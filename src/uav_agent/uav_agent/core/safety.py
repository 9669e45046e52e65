"""The safety filter (`policies: {safety: filter}`, docs/vehicle.md): the acceleration a multirotor MAP commands
is the one nearest to eq. 9's (the nominal) that keeps its distance from every MAP its traffic receiver reports,
keeps the links it protects (rule 'links') and stays within its envelope.

One small QP per MAP and step, decided from its own state and what the others broadcast:

    minimise  |u - u_nom|^2 + SLACK_COST s + LINK_COST sum(s_l)   (u: the horizontal acceleration; slacks >= 0)
    subject to  m_ij . u <= its bound + s                                         per reported MAP j (separation)
               -n_il . u <= share_il (KAPPA h_il - h_il' o_il - w_il^2 / d_il) + s_l   per protected link l
                e_k . u <= a_max cos(pi / SIDES)                                   the polygon inside the disc a_max
                u . p / |p| <= (v_max - |p|) / (tau + STEP_S)                      the speed within v_max

h_ij = v_safe(d_ij - keep) - c_ij is the pairwise barrier for double integrators of Wang, Ames and Egerstedt
(IEEE T-RO 2017): c the speed at which i and j close, w their speed sideways, n the unit vector from i to j, and
v_safe(g) the closing speed from which both, braking at BRAKE_SHARE a_max each after the lag and the step's hold,
stop within g (g = v T + v^2 / (4 a), T = tau + STEP_S: the lag's room is what sets it apart from their sqrt law).
Its derivative along the pair's motion is n . (a_j - a_i) + w^2 / d - v_safe' c; each MAP takes half of each pair's
budget, as they do, so ḣ >= -KAPPA h holds when both do their half (row m_ij = n_ij, bound (KAPPA h_ij - h_ij' c_ij
+ w_ij^2 / d_ij) / 2). It brakes a pair that would pass wide of keep as hard as one head-on, so each pair has a
second barrier, the collision cone (Thontepu et al., collision-cone CBFs, 2022): h = |v| (cos phi - cos theta),
the relative velocity at theta from the line of centres, outside the cone of half-angle asin(keep / d) when
h >= 0. Either keeps the pair apart, so the row is that of the one with most room (the union of their safe sets,
as Glotfelter, Cortés and Egerstedt compose barriers, 2017): a pair passing wide flies on, one that would not is
turned aside before it is braked. Separation is hard against the nominal (the slack's linear price outbids any
nominal), soft only against the envelope, which the vehicle enforces anyway.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import daqp
import numpy as np
from numpy.typing import NDArray

from .ablation import on
from .envelope import STEP_S, lengths, saturate
from .params import FlockParams
from .potentials import F64

KAPPA = 2.0         # /s: how fast the barrier may be used up, ḣ >= -KAPPA h (at most 1 / (tau + STEP_S))
BRAKE_SHARE = 0.5   # of a_max, each MAP's braking the barrier plans with: the rest is the lag's and the gusts'
SIDES = 8           # the acceleration disc as the polygon of SIDES sides inside it (a QP has linear rows)
SLACK_COST = 1e4    # (m/s^2 per unit slack): far above a protected link's, so separation gives way only to the envelope
LINK_COST = 1e2     # a protected link's slack: above what the nominal, within a_max, can pull (2 a_max), below separation
SLACK_WEIGHT = 1e-6  # the slacks' quadratic weight, only to keep the QP's Hessian positive definite
SHARE_FLOOR = 0.5   # m/s: what each end of a protected link counts as its opening speed at least (opening_share)
FLAG_TOL = 1e-6     # m/s^2: how far past a link's row a command must be for the flags to count it
LINK_MARGIN = 1.0   # m: a protected link is kept this much shorter than r, where the chains are laid taut
# What the filter did to a MAP's command at a step (Filtered.flags, bits; Command.msg's filter): a protected link
# whose row it could not keep (its slack gave way), and a protected link that stopped the nominal, which would
# have opened it faster than its barrier allows (the MAP held back from where eq. 9 sends it); with the agent's
# (agent.after_filter): held back while farther than OFF_GOAL from its goal, and protecting no link (rule 'release').
RELAXED, HELD, AWAY, RELEASED = 1, 2, 4, 8
# Rule 'release', the filter's liveness: a MAP held back from its goal for RELEASE_S without a break protects no
# link for FREE_S, then counts again. Held back means a protected link stopped it while it was more than OFF_GOAL of d
# from where its goal term aims (a settled MAP whose nominal only jitters against a taut link is not kept from anything).
RELEASE_S = 10.0
FREE_S = 5.0
OFF_GOAL = 0.5
_ANGLES = 2.0 * np.pi * np.arange(SIDES) / SIDES
_FACES = np.column_stack([np.cos(_ANGLES), np.sin(_ANGLES)])
_APOTHEM = math.cos(math.pi / SIDES)


def horizon(fp: FlockParams) -> float:
    """The time (s) before a command takes effect: the autopilot's lag and the step's hold."""
    return fp.tau + STEP_S


def braking(fp: FlockParams) -> float:
    """Each MAP's braking (m/s^2) that the barrier plans with."""
    return BRAKE_SHARE * fp.a_max


def _barrier(dq: F64, dv: F64, fp: FlockParams, sign: float, share: F64 | float,
             wide: F64 | float = 0.0) -> tuple[F64, F64]:
    """The one braking-curve barrier of both rows: the speed s = sign n . dv at which the pair uses up its gap
    (closing, sign -1, against `keep`; opening, sign +1, against r - LINK_MARGIN - wide) kept below v_safe(gap), and
    this MAP's share of the acceleration budget that keeps it so; with the barrier h = v_safe(gap) - s itself.
    Sideways speed w closes a gap that opens (w^2 / d) and opens one that closes."""
    a, t = braking(fp), horizon(fp)
    dist = np.maximum(lengths(dq), 1e-9)
    speed = sign * (dq * dv).sum(axis=-1) / dist
    sideways2 = np.maximum((dv * dv).sum(axis=-1) - speed * speed, 0.0)
    gap = dist - fp.keep if sign < 0 else fp.r - LINK_MARGIN - wide - dist
    root = np.sqrt(t * t + np.maximum(gap, 0.0) / a)
    h = 2.0 * a * (root - t) - speed  # v_safe(gap) less the speed
    return share * (KAPPA * h - speed / root - sign * sideways2 / dist), h


def line_budget(dq: F64, dv: F64, fp: FlockParams) -> F64:
    """Per pair (j at dq from i, moving at dv relative to it), the most of i's acceleration towards j that keeps
    the braking barrier along their line of centres: n . a_i <= line_budget (m/s^2). Symmetric: j's is the same."""
    return _barrier(dq, dv, fp, -1.0, 0.5)[0]


def _cone(dq: F64, dv: F64, fp: FlockParams) -> tuple[F64, F64, F64]:
    """The collision cone's barrier per pair: h = |v| (cos phi - cos theta) (m/s), the relative velocity v at
    theta from the line of centres, outside the cone of half-angle phi = asin(keep / d) when h >= 0; and the
    unit row for i's acceleration with i's half of the budget that keeps ḣ >= -KAPPA h."""
    p, v = -dq[:, :2], -dv[:, :2]  # i's position and velocity relative to j
    dist = np.maximum(lengths(p), 1e-9)
    speed = np.maximum(lengths(v), 1e-9)
    s = np.sqrt(np.maximum(dist * dist - fp.keep * fp.keep, 1e-9))
    pv = (p * v).sum(axis=1)
    num = pv + speed * s
    h = num / dist
    grad = (p + v * (s / speed)[:, None]) / dist[:, None]  # ḣ = grad . (a_i - a_j) + drift
    drift = (speed * speed + speed * pv / s) / dist - num * pv / dist ** 3
    norm = np.maximum(lengths(grad), 1e-9)
    return h, -grad / norm[:, None], 0.5 * (KAPPA * h + drift) / norm


def separation(dq: F64, dv: F64, fp: FlockParams) -> tuple[F64, F64]:
    """Per pair (j at dq from i, moving at dv relative to it), the row that keeps it apart: i's acceleration along
    the row's unit direction at most its bound (m/s^2), j's alike. Two barriers, either of which keeps the pair
    apart (the union of their safe sets): braking along the line of centres, and the collision cone, which lets
    a pair that will pass wide of keep fly on and turns aside one that would not. Of those not used up, the one
    with most room; with both used up, the one less so. The cone alone holds no pair at rest, and none within
    keep."""
    n = dq[:, :2] / np.maximum(lengths(dq[:, :2]), 1e-9)[:, None]
    b, h_line = _barrier(dq, dv, fp, -1.0, 0.5)
    if not len(dq):
        return n, b
    h_cone, c_row, c_b = _cone(dq, dv, fp)
    can = (lengths(dq[:, :2]) > fp.keep) & (lengths(dv[:, :2]) > 1e-6)
    cone = can & np.where((h_line >= 0.0) & (h_cone >= 0.0), c_b > b, h_cone > h_line)
    return np.where(cone[:, None], c_row, n), np.where(cone, c_b, b)


def budget(dq: F64, dv: F64, fp: FlockParams) -> F64:
    """Per pair, the bound of its separation row (separation): below a_max, a command within the envelope can
    reach it (binding), and the lower, the more urgent (what the traffic receiver passes on first)."""
    return separation(dq, dv, fp)[1]


def opening_share(dq: F64, own_p: F64, nbr_p: F64) -> F64:
    """Per link both ends keep (state.SHARED), the own MAP's share of the pair's budget: in proportion to how fast
    each end flies away from the other (SHARE_FLOOR m/s each added, so half each while both hold still). The MAP
    that opens the link brakes for it, and the one it leaves stays where the network has it; the two shares add up
    to the whole, so the link holds when both do theirs, and both ends compute them alike from the same broadcasts.
    A link one end keeps alone (state.ALONE) is its whole budget."""
    n = dq / np.maximum(lengths(dq), 1e-9)[:, None]
    own, other = np.maximum(-(n * own_p).sum(axis=1), 0.0), np.maximum((n * nbr_p).sum(axis=1), 0.0)
    return (own + SHARE_FLOOR) / (own + other + 2.0 * SHARE_FLOOR)


def link_budget(dq: F64, dv: F64, fp: FlockParams, share: F64 | float = 0.5, wide: F64 | float = 0.0) -> F64:
    """Per protected link (j at dq from i, moving at dv relative to it), the most of i's acceleration away from j
    that keeps the link's barrier h = v_safe(r - LINK_MARGIN - wide - d) - o (o the speed at which the link opens):
    -n . a_i <= link_budget. The sideways speed w opens a link at w^2 / d and counts against it; wide is what the
    link's margin grows by while j's state is old (stale_margin)."""
    return _barrier(dq, dv, fp, 1.0, share, wide)[0]


def stale_margin(age: F64, fp: FlockParams) -> F64:
    """How much farther apart (m) two MAPs may be than a neighbour's state `age` s old places them (flown on at its
    velocity then, ear.py's rule 'predict'): each accelerating away from the other at a_max since, a_max age^2 in
    all. A link's margin grows by it, so the filter keeps a link it hears late as surely as one it hears now."""
    return fp.a_max * np.asarray(age, dtype=float) ** 2


def protected(owner: NDArray[np.intp], dq: F64, m: int, asked: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Per link (owner, j at dq from it; the links the network needs that its radio hears, grouped by owner, as
    the allocation names them: Allocation.needed) of those asked, whether the owner protects it: the links of their
    relative-neighbourhood graph, those no third neighbour k witnesses, max(d_ik, d_jk) < d_ij.

    The graph contains the minimum spanning tree of the links (Toussaint 1980), so over all MAPs the protected links
    span every connected part of the graph of the links given; both ends decide alike from the same broadcasts (a
    witness lies within r of both), and a link stops being protected only once a witness joins its ends through two
    shorter links, themselves protected or witnessed in turn by shorter ones: make before break."""
    out = asked.copy()
    first = np.searchsorted(owner, np.arange(m + 1))
    for i in np.unique(owner[asked]):
        lo, hi = first[i], first[i + 1]
        if hi - lo < 2:
            continue
        block = dq[lo:hi]
        d = lengths(block)
        apart = lengths(block[:, None, :] - block[None, :, :])
        out[lo:hi] &= ~(np.maximum(apart, d[None, :]) < d[:, None]).any(axis=1)
    return out


def held_next(held: int, flags: int, off_goal: float, fp: FlockParams) -> tuple[int, int]:
    """Rule 'release': a MAP's count after this step (held: steps held back from its goal without a break; below
    0: steps left free of its links) and the AWAY, RELEASED bits this step adds to its flags."""
    if held < 0:
        return held + 1, RELEASED
    if not flags & HELD or off_goal <= OFF_GOAL * fp.d:
        return 0, 0
    if held + 1 >= round(RELEASE_S / STEP_S) and on('release'):
        return -round(FREE_S / STEP_S), AWAY
    return held + 1, AWAY


def binding(dq: F64, dv: F64, fp: FlockParams) -> NDArray[np.bool_]:
    """The pairs whose barrier an acceleration within a_max can reach: the only rows a MAP's QP needs (what its
    traffic receiver passes on, vehicle.traffic)."""
    return budget(dq, dv, fp) < fp.a_max


def reach(closing: float, fp: FlockParams) -> float:
    """The distance (m) beyond which no pair closing at most at `closing` m/s binds (binding is False), whatever
    it flies sideways: budget >= KAPPA (v_safe - c) / 2 - c / (2 T), so v_safe >= c + (2 a_max + c / T) / KAPPA
    is enough."""
    t, a = horizon(fp), braking(fp)
    v = closing + (2.0 * fp.a_max + closing / t) / KAPPA
    return fp.keep + v * t + v * v / (4.0 * a)


class Filtered(NamedTuple):
    """Each own MAP's command (m rows) and what the filter did to it (RELAXED, HELD bits; 0: nothing of either)."""

    u: F64
    flags: NDArray[np.uint8]


def filtered(u_nom: F64, own_p: F64, owner: NDArray[np.intp], dq: F64, dv: F64, fp: FlockParams,
             links: tuple[NDArray[np.intp], F64, F64, NDArray[np.bool_], F64] | None = None) -> Filtered:
    """Each own MAP's command: u_nom (its z kept) filtered through the QP above, the pairs to keep apart as rows
    (owner, j's position less i's, j's velocity less i's) grouped by owner, and likewise the protected links to
    keep, with whether the owner keeps each alone (state.ALONE; else its opening_share) and how much its margin
    grows while j's state is old (stale_margin, m); none: no link rows."""
    m = len(u_nom)
    l_owner, l_dq, l_dv, alone, l_wide = links if links is not None else (
        np.zeros(0, np.intp), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, bool), np.zeros(0))
    l_first = np.searchsorted(l_owner, np.arange(m + 1))
    l_n = l_dq[:, :2] / np.maximum(lengths(l_dq[:, :2]), 1e-9)[:, None]
    l_b = link_budget(l_dq, l_dv, fp, np.where(alone, 1.0, opening_share(l_dq, own_p[l_owner], own_p[l_owner] + l_dv)),
                      l_wide)
    out, flags = u_nom.copy(), np.zeros(m, dtype=np.uint8)
    limit = fp.a_max * _APOTHEM
    speed = lengths(own_p[:, :2])
    heading = own_p[:, :2] / np.maximum(speed, 1e-12)[:, None]
    room = np.maximum((fp.v_max - speed) / horizon(fp), -limit)
    moving = speed > 1e-9
    first = np.searchsorted(owner, np.arange(m + 1))
    n, b = separation(dq, dv, fp)
    nominal = saturate(u_nom[:, :2], fp.a_max)  # within a_max first: what a link slack's price must outbid is 2 a_max
    outside = ((nominal @ _FACES.T) > limit).any(axis=1) | (moving & ((nominal * heading).sum(axis=1) > room))
    for i in np.flatnonzero(outside | (first[1:] > first[:-1]) | (l_first[1:] > l_first[:-1])):
        lo, hi, l_lo, l_hi = first[i], first[i + 1], l_first[i], l_first[i + 1]
        # variables (s_sep, one slack per protected link, ux, uy); rows: separation, protected links, polygon, speed
        links_here = l_hi - l_lo
        rows = [np.c_[-np.ones(hi - lo), np.zeros((hi - lo, links_here)), n[lo:hi]],
                np.c_[np.zeros(links_here), -np.eye(links_here), -l_n[l_lo:l_hi]],
                np.c_[np.zeros((SIDES, 1 + links_here)), _FACES]]
        upper = [b[lo:hi], l_b[l_lo:l_hi], np.full(SIDES, limit)]
        if moving[i]:
            rows.append(np.r_[np.zeros(1 + links_here), heading[i]][None, :])
            upper.append(room[i:i + 1])
        a_rows = np.ascontiguousarray(np.concatenate(rows))
        bu = np.concatenate([np.full(1 + links_here, np.inf), *upper])
        bl = np.concatenate([np.zeros(1 + links_here), np.full(len(a_rows), -np.inf)])
        cost = np.r_[SLACK_COST, np.full(links_here, LINK_COST), -nominal[i]]
        x, _, flag, _ = daqp.solve(np.diag(np.r_[np.full(1 + links_here, SLACK_WEIGHT), 1.0, 1.0]), cost, a_rows, bu, bl)
        if flag < 1:  # no command within the envelope (cannot happen while the speed is within v_max): brake
            x = np.r_[np.zeros(1 + links_here), -heading[i] * limit]
        out[i, :2] = x[-2:]
        if links_here:
            pull = -l_n[l_lo:l_hi] @ np.stack([nominal[i], x[-2:]], axis=1) > l_b[l_lo:l_hi, None] + FLAG_TOL
            flags[i] = RELAXED * pull[:, 1].any() + HELD * pull[:, 0].any()
    return Filtered(out, flags)
