"""Eq. 9 flown within a multirotor's envelope: what a MAP commands when its speed, acceleration and the
distance it keeps from others are bounded (scenario `vehicle:`, docs/vehicle.md).

Six rules, each switched off by name (ablation.VEHICLE_RULES); none acts on the paper's vehicle, whose
FlockParams have a_max = 0:
- 'lead' and 'soften': the flocking terms taken ahead of the lag, and softened (flocking_within);
- 'brake': the goal terms of eq. 12-13 aim at a speed the MAP can still stop from before its goal, within its
  cruise speed;
- 'keep': a MAP brakes along each link on which it closes faster than it could stop before `keep` m;
- 'traffic': those links are to the MAPs whose broadcasts its traffic receiver passes on (control.control_input),
  heard far enough out to stop from v_max, not to the neighbours its radio hears within r;
- 'swerve': and on a link whose closest approach falls within `keep` m, it turns away from it (to its right when
  head-on, as pilots do), which the pair can still do where braking alone no longer stops them;
- 'priority': that braking is served first from the acceleration budget, eq. 9's terms from what is left.
"""
from __future__ import annotations

from typing import Callable

import numpy as np
from numpy.typing import NDArray

from .ablation import on
from .params import FlockParams
from .potentials import F64

BRAKE_SHARE = 0.5  # of a_max, what a goal term plans to stop with: the rest is for the flocking terms and the lag
LEAD_LAGS = 4.0    # rule 'lead': how many lags ahead the flocking terms are taken ...
STEP_S = 0.1       # ... each lag with the step's hold (dt of every shipped scenario) added
SOFTEN = 0.5       # rule 'soften': the flocking terms' share a lagged MAP flies


def limited(fp: FlockParams) -> bool:
    """Whether the MAP flies within an envelope (a multirotor), not the paper's double integrator."""
    return fp.a_max > 0.0


def stopping_speed(distance: F64, fp: FlockParams) -> F64:
    """The speed from which a MAP stops within `distance` at BRAKE_SHARE * a_max, after its lag tau, within v_max."""
    a = BRAKE_SHARE * fp.a_max
    d = np.maximum(np.asarray(distance, dtype=float), 0.0)
    v = -a * fp.tau + np.sqrt((a * fp.tau) ** 2 + 2.0 * a * d)  # v tau + v^2 / 2a = d
    return np.minimum(v, fp.v_max)  # the speed the MAP plans to fly at most: the vehicle's cruise, or its v_max


def braking_room(closing: F64 | float, a_max: float, tau: float) -> F64 | float:
    """The room (m) a MAP closing at `closing` m/s covers before it has stopped: its lag at that speed, then braking
    at a_max. Rule 'keep' acts on a link whose distance less this room is below keep (keep_apart; vehicle.traffic
    passes a MAP exactly those links)."""
    return closing * tau + closing ** 2 / (2.0 * a_max)


def sight_speed(r: float, keep: float, a_max: float, tau: float) -> float:
    """The cruise speed at which two MAPs meeting head-on where they first hear each other (r apart) stop keep m
    short, each braking at a_max after its lag: 2 v tau + v^2 / a_max = r - keep (docs/vehicle.md)."""
    room = max(r - keep, 0.0)
    return float(a_max * (-tau + np.sqrt(tau ** 2 + room / a_max)))


def capped(velocity: F64, distance: F64, fp: FlockParams) -> F64:
    """Rule 'brake': a goal term's velocity (rows) shortened to stopping_speed(distance)."""
    if not (limited(fp) and on('brake')):
        return velocity
    speed = lengths(velocity)[..., None]
    cap = stopping_speed(distance, fp)[..., None]
    over = speed > cap
    if not over.any():
        return velocity
    return np.where(over, velocity * (cap / np.maximum(speed, 1e-12)), velocity)


def spring(fp: FlockParams) -> float:
    """The goal term's spring c1 / c2 (a speed per metre of error, eq. 12 as a velocity loop). Rule 'shape': softened
    with the flocking terms (rule 'soften'), so that a server comes to rest where eq. 9 puts it. Halving the lattice's
    springs and not the goal's squeezed each cluster's lattice about its goal (nearest neighbours 14 m apart where the
    ideal vehicle's are 16 m), and the cluster's outer users went unserved."""
    return fp.c1 / fp.c2 * (SOFTEN if on('soften') and on('shape') else 1.0)


def flocking_within(terms: Callable[..., F64], own_q: F64, own_p: F64, own_nu: F64, owner: NDArray[np.intp],
                    nbr_q: F64, nbr_p: F64, nbr_nu: F64, fp: FlockParams, apart: NDArray[np.integer] | None,
                    axis: F64 | None = None) -> F64:
    """Eq. 9's flocking terms (control.flocking_terms) as a lagged MAP flies them.

    Rule 'lead': taken where the MAP and its neighbours will be LEAD_LAGS (tau + STEP_S) ahead at their
    velocities. A link of Phi is a spring of up to 6 /s^2 at d; behind a lag tau a spring needs damping above
    tau times its stiffness or it oscillates, and the lead gives each link that damping (a dashpot of the
    spring's stiffness times the lead). Rule 'soften': the terms scaled by SOFTEN, the springs with them.
    """
    lead = LEAD_LAGS * (fp.tau + STEP_S) if on('lead') else 0.0
    u = terms(own_q + lead * own_p, own_p, own_nu, owner, nbr_q + lead * nbr_p, nbr_p, nbr_nu, fp, apart, axis)
    return SOFTEN * u if on('soften') else u


def keep_apart(own_q: F64, own_p: F64, owner: NDArray[np.intp], nbr_q: F64, nbr_p: F64, fp: FlockParams) -> F64:
    """Rule 'keep': per own MAP, the braking along its links that lets it stop `keep` m short of each neighbour.

    On a link closing at c (m/s) with gap g = distance - keep - c tau, the MAP may close at sqrt(2 a_max g); it
    brakes the excess away within tau (and at once, at a_max, when already inside keep). A pair whose ends both
    do so stops short whatever eq. 9 asks for, provided they first see each other far enough apart: from r,
    closing no faster than twice sight_speed; the traffic receiver's 100 m suffice from v_max (docs/vehicle.md).
    """
    m = own_q.shape[0]
    out = np.zeros((m, 3))
    if owner.size == 0 or not on('keep'):
        return out
    dq = nbr_q - own_q[owner]
    dist = np.maximum(lengths(dq), 1e-9)
    n = dq / dist[:, None]
    closing = np.einsum('ij,ij->i', own_p[owner] - nbr_p, n)
    gap = np.maximum(dist - fp.keep - np.maximum(closing, 0.0) * fp.tau, 0.0)
    excess = np.maximum(closing - np.sqrt(2.0 * fp.a_max * gap), 0.0)
    push = np.minimum(excess / max(fp.tau, 1e-3), fp.a_max) + fp.a_max * np.clip((fp.keep - dist) / fp.keep, 0.0, 1.0)
    edges = -n * push[:, None]
    if on('swerve'):
        edges = edges + swerve(dq, nbr_p - own_p[owner], excess > 0.0, fp)
    for axis in range(3):
        out[:, axis] = np.bincount(owner, weights=edges[:, axis], minlength=m)
    return saturate(out, fp.a_max)


def swerve(dq: F64, dv: F64, braking: NDArray[np.bool_], fp: FlockParams) -> F64:
    """Rule 'swerve': per link (neighbour at dq, moving at dv relative to the MAP) on which rule 'keep' is braking,
    a_max away from where the neighbour will be at their closest approach, if that falls within keep m.

    Braking from a closing speed c needs c^2 / 2 a_max of room, turning aside by keep only about keep / c of time:
    two MAPs crossing at 15 m/s each cannot stop within r of each other, but they can still miss. Both ends of a
    link turn away from each other, so the pair's miss distance grows at 2 a_max; head-on (no side to turn away
    from) each turns to its right, which is again away from the other.
    """
    speed2 = np.maximum(np.einsum('ij,ij->i', dv, dv), 1e-12)
    t_cpa = np.maximum(-np.einsum('ij,ij->i', dq, dv) / speed2, 0.0)
    miss = dq + dv * t_cpa[:, None]
    gap = lengths(miss)
    right = np.column_stack([dv[:, 1], -dv[:, 0], np.zeros(len(dv))]) / np.sqrt(speed2)[:, None]
    side = np.where((gap > 1e-3)[:, None], -miss / np.maximum(gap, 1e-12)[:, None], right)
    return side * (fp.a_max * (braking & (gap < fp.keep)))[:, None]


def lengths(rows: F64) -> F64:
    """The Euclidean length of each row: np.linalg.norm(rows, axis=-1) to the bit, at two thirds of its time (the
    envelope's rules take a dozen a step, each over a few hundred rows)."""
    return np.sqrt((rows * rows).sum(axis=-1))


def saturate(u: F64, bound: F64 | float) -> F64:
    """Rows shortened to at most `bound` (per row or for all), their direction kept; u itself when none is longer."""
    norm = lengths(u)
    over = norm > bound
    if not over.any():  # most rows of most steps: as they are
        return u
    scale = np.where(over, np.asarray(bound) / np.maximum(norm, 1e-12), 1.0)
    return u * scale[:, None]


def governor(own_p: F64, fp: FlockParams) -> F64:
    """Rule 'brake' for a MAP faster than it plans to fly (cruise): the excess taken off within tau, along its
    velocity; nothing while it flies within its cruise speed."""
    speed = lengths(own_p)
    if not (on('brake') and (speed > fp.v_max).any()):  # most steps: every MAP within its cruise speed
        return np.zeros_like(own_p)
    over = np.maximum(speed - fp.v_max, 0.0)
    return -own_p / np.maximum(speed, 1e-12)[:, None] * np.minimum(over / max(fp.tau, 1e-3), fp.a_max)[:, None]


def command(u: F64, brake: F64, fp: FlockParams) -> F64:
    """Rule 'priority': the acceleration a MAP commands from eq. 9's u and the braking of rule 'keep'.

    The braking takes what it needs of a_max first and eq. 9 the rest, so no goal or flocking term can
    spend the budget a MAP needs to keep its distance. Off, the two are summed and clipped together.
    """
    if not brake.any():  # most steps: nothing to brake for, and the sums below come to this, to the bit
        return saturate((saturate(u, fp.a_max) if on('priority') else u) + 0.0, fp.a_max)
    brake = saturate(brake, fp.a_max)
    if on('priority'):
        left = np.maximum(fp.a_max - lengths(brake), 0.0)
        return saturate(brake + saturate(u, left), fp.a_max)
    return saturate(u + brake, fp.a_max)
