"""The control input u_i = f_i + g_i + h_i of eq. 9, for a batch of MAPs at once.

Every function takes the MAPs it computes for ("own", m rows) and their neighbour links ("edges", one row
per ordered pair i -> j, grouped by owner in ascending neighbour id). A MAP's node calls them with m = 1,
the batch simulator with all MAPs; both sum the edges with the same sequential reduction, so the two give
bit-identical results for the same inputs.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from . import envelope, safety
from .ablation import on
from .clusters import segment_distance
from .params import FlockParams
from .potentials import F64, action, bump, sigma_abs, sigma_grad, sigma_norm
from .state import ALONE, APART, INLINE, M1, PASSING


def sum_edges(values: F64, owner: NDArray[np.intp], m: int) -> F64:
    """Sum per-edge 3-vectors into their owners, sequentially in edge order (deterministic)."""
    out = np.zeros((m, values.shape[1]))
    for axis in range(values.shape[1]):
        out[:, axis] = np.bincount(owner, weights=values[:, axis], minlength=m)
    return out


def overload_weight(n_users: F64, fp: FlockParams) -> F64:
    """1 - alpha_{0,1}(||(N_u - N_max)^+||_sigma / ||N_max||_sigma): grows as a MAP exceeds N_max (eq. 10)."""
    excess = np.maximum(np.asarray(n_users, dtype=float) - fp.n_max, 0.0)
    return 1.0 - bump(sigma_abs(excess, fp.epsilon) / sigma_abs(fp.n_max, fp.epsilon), 0.0, 1.0)


def spare_weight(n_users: F64, fp: FlockParams) -> F64:
    """1 - alpha_{0,1}(||(N_max - N_u)^+||_sigma / ||N_max||_sigma): velocity-consensus weight of g_i.

    A MAP with no users matches its neighbours fully; one at capacity stops matching and holds its users.
    """
    spare = np.maximum(fp.n_max - np.asarray(n_users, dtype=float), 0.0)
    return 1.0 - bump(sigma_abs(spare, fp.epsilon) / sigma_abs(fp.n_max, fp.epsilon), 0.0, 1.0)


def flocking_terms(own_q: F64, own_p: F64, own_nu: F64, owner: NDArray[np.intp],
                   nbr_q: F64, nbr_p: F64, nbr_nu: F64, fp: FlockParams,
                   apart: NDArray[np.integer] | None = None, axis: F64 | None = None) -> F64:
    """f_i + g_i (eq. 10 and the consensus term) for every own MAP from its neighbours' q, p, N_u.

    apart says what each link is (state.RELATED, APART, PASSING; demand allocation). Unrelated MAPs keep
    the repulsion of Phi, so no two collide, but neither attract nor match velocities, so groups bound for
    different places part instead of dragging one another. A MAP on its way to a new role keeps only d/2
    from the MAPs it passes: kept at d by the servers on the rim of a cluster, it slid round the disc and
    left it off the relay chain, out of everyone's range (docs/notes/dynamics.md, "Passing at d/2"). An INLINE
    link (rule 'inline') is all of eq. 10 on the offset along the own MAP's edge, axis (m, 3) its unit vector.
    """
    m = own_q.shape[0]
    if owner.size == 0:
        return np.zeros((m, 3))
    dq = nbr_q - own_q[owner]
    if apart is not None and axis is not None and (apart == INLINE).any():
        along = apart == INLINE
        u = axis[owner[along]]
        dq[along] = np.einsum('ij,ij->i', dq[along], u)[:, None] * u
    z = sigma_norm(dq, fp.epsilon)
    gain = action(z, fp.d, fp.r, fp.epsilon, fp.a, fp.b, fp.gamma) + fp.a * overload_weight(nbr_nu, fp)
    spare = spare_weight(own_nu[owner], fp)
    repel = None if apart is None else (apart == APART) | (apart == PASSING)
    if repel is not None and repel.any():
        gain = np.where(repel, np.minimum(gain, 0.0), gain)
        passing = apart == PASSING
        if passing.any():  # Phi's action again, with d/2 for d, on those links only
            gain[passing] = np.minimum(action(z[passing], fp.d / 2, fp.r, fp.epsilon, fp.a, fp.b, fp.gamma), 0.0)
        spare = np.where(repel, 0.0, spare)
    f_edges = gain[:, None] * sigma_grad(dq, fp.epsilon)
    g_edges = spare[:, None] * (nbr_p - own_p[owner])
    return sum_edges(f_edges + g_edges, owner, m)


def goal_term(q: F64, p_vel: F64, q_ref: F64, fp: FlockParams, v_ref: F64 | float = 0.0) -> F64:
    """h_i for M0 and M2, eq. 12: a spring to the goal q^r with damping to its velocity p^r (zero for a
    cluster that stands still, the survey's estimate for one that moves).

    Within an envelope it is the same velocity loop, c2 (v^r + (c1/c2)(q^r - q) - p), with the spring's speed
    (c1/c2)(q^r - q) capped at one the MAP can stop from before q^r (rule 'brake', envelope.capped).
    """
    if not envelope.limited(fp):
        return fp.c1 * (q_ref - q) + fp.c2 * (v_ref - p_vel)
    error = q_ref - q
    return fp.c2 * (v_ref + envelope.capped(envelope.spring(fp) * error, np.linalg.norm(error, axis=-1), fp) - p_vel)


def bridge_term(q: F64, p_vel: F64, q1: F64, q2: F64, fp: FlockParams,
                v1: F64 | float = 0.0, v2: F64 | float = 0.0) -> F64:
    """h_i for M1, eq. 13: descend E_c toward the segment q1-q2, damped toward the two clusters' velocities."""
    d1, d2 = q1 - q, q2 - q
    pull = (fp.k * d1 / (1.0 + fp.epsilon * sigma_norm(d1, fp.epsilon))[..., None]
            + fp.k * d2 / (1.0 + fp.epsilon * sigma_norm(d2, fp.epsilon))[..., None])
    # Eq. 13 damps toward each of the two clusters' velocities with half of c2 (zero while they stand still).
    if not envelope.limited(fp):
        return pull + 0.5 * fp.c2 * (v1 - p_vel) + 0.5 * fp.c2 * (v2 - p_vel)
    # Within an envelope: the pull's speed pull / c2 capped by the distance to the segment (rule 'brake').
    rows = zip(np.reshape(q, (-1, 3)), np.reshape(q1, (-1, 3)), np.reshape(q2, (-1, 3)))
    off = np.array([segment_distance(x, a[:2], b[:2]) for x, a, b in rows]).reshape(np.shape(q)[:-1])
    rest = envelope.capped(pull / fp.c2, off, fp)
    return fp.c2 * (0.5 * (v1 + v2) + rest - p_vel)



def edge_axes(mode: NDArray[np.integer], q1: F64, q2: F64) -> F64:
    """Per own MAP, the unit vector along the piece of edge q1-q2 its bridge term aims at (relay_slot lays it along
    the edge); zero for a MAP not in M1 or a piece of no length. What rule 'inline' spaces fellow relays along."""
    piece = np.where((np.asarray(mode) == M1)[:, None], q2 - q1, 0.0)
    piece[:, 2] = 0.0
    norm = np.linalg.norm(piece, axis=1, keepdims=True)
    return np.where(norm > 1e-9, piece / np.maximum(norm, 1e-12), 0.0)


def connectivity_potential(q: F64, q1: F64, q2: F64, fp: FlockParams) -> F64:
    """E_c of eq. 6: zero at the segment's ends, nearly flat along it and rising away from it."""
    return fp.k * (sigma_norm(q1 - q, fp.epsilon) + sigma_norm(q2 - q, fp.epsilon) - sigma_norm(q1 - q2, fp.epsilon))


class Control(NamedTuple):
    """u_i for every own MAP, what the safety filter did to each (safety.RELAXED, HELD bits; 0 without it), and the
    nominal it started from (eq. 9 as the vehicle flies it, before the filter or the rules' braking): why a MAP
    moved is the nominal, then what the filter or the rules made of it (`uav-flock trace`)."""

    u: F64
    flags: NDArray[np.uint8]
    nominal: F64


def control_input(own_q: F64, own_p: F64, own_nu: F64, mode: NDArray[np.integer], target: F64,
                  bridge_a: F64, bridge_b: F64, owner: NDArray[np.intp], nbr_q: F64, nbr_p: F64,
                  nbr_nu: F64, fp: FlockParams, apart: NDArray[np.integer] | None = None,
                  ref_vel: F64 | None = None,
                  traffic: tuple[NDArray[np.intp], F64, F64] | None = None,
                  needed: NDArray[np.integer] | None = None, nbr_age: F64 | None = None) -> Control:
    """u_i of eq. 9 for every own MAP: flocking terms plus the goal term its mode selects.

    target is q^r for M0/M2 rows; bridge_a/bridge_b are q_1^r/q_2^r for M1 rows (ignored elsewhere);
    ref_vel (n, 3, 3) the velocities of target, bridge_a and bridge_b (None: all still); traffic the owner row,
    position and velocity of each broadcast the MAPs' traffic receivers took in (rule 'traffic'); needed, per
    neighbour link, who keeps it if the network needs it kept (agent.Plan.needed, state.UNKEPT, SHARED or ALONE;
    None: none is); nbr_age how old each neighbour's state is (s; None: all of this step).
    """
    if envelope.limited(fp):
        u = envelope.flocking_within(flocking_terms, own_q, own_p, own_nu, owner, nbr_q, nbr_p, nbr_nu, fp, apart,
                                     edge_axes(mode, bridge_a, bridge_b))
    else:
        u = flocking_terms(own_q, own_p, own_nu, owner, nbr_q, nbr_p, nbr_nu, fp, apart)
    bridging = np.asarray(mode) == M1
    v = np.zeros((len(own_q), 3, 3)) if ref_vel is None else ref_vel
    h = goal_term(own_q, own_p, target, fp, v[:, 0])
    if np.any(bridging):
        h[bridging] = bridge_term(own_q[bridging], own_p[bridging], bridge_a[bridging], bridge_b[bridging], fp,
                                  v[bridging, 1], v[bridging, 2])
    none = np.zeros(len(own_q), dtype=np.uint8)
    nominal = u + h
    if not envelope.limited(fp):
        return Control(nominal, none, nominal)
    seen = traffic if traffic is not None and fp.traffic > 0 and on('traffic') else (owner, nbr_q, nbr_p)
    if fp.safety == 'filter':  # nominal, then the one filter, then the command
        by, at, vel = seen
        dq, dv = at - own_q[by], vel - own_p[by]
        rows = np.flatnonzero(safety.binding(dq, dv, fp))
        links = None
        if on('links') and needed is not None and needed.any():  # the links it protects, of those the network needs
            ask = np.flatnonzero(needed)
            l_owner, l_dq, l_dv = owner[ask], nbr_q[ask] - own_q[owner[ask]], nbr_p[ask] - own_p[owner[ask]]
            l_wide = safety.stale_margin(np.zeros(len(ask)) if nbr_age is None else nbr_age[ask], fp)
            near = safety.link_budget(l_dq, l_dv, fp, 0.5, l_wide) < fp.a_max  # the rows a command within a_max can reach
            chosen = np.flatnonzero(safety.protected(l_owner, l_dq, len(own_q), near))
            links = l_owner[chosen], l_dq[chosen], l_dv[chosen], needed[ask][chosen] == ALONE, l_wide[chosen]
        return Control(*safety.filtered(nominal, own_p, by[rows], dq[rows], dv[rows], fp, links), nominal)
    brake = envelope.keep_apart(own_q, own_p, *seen, fp) + envelope.governor(own_p, fp)
    return Control(envelope.command(nominal, brake, fp), none, nominal)
