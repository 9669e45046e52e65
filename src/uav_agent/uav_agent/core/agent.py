"""One MAP's whole step, as its node runs it: neighbours' messages and own sensing in, u_i and memory out."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .control import control_input
from .clusters import ClusterMap
from .params import FlockParams
from .policies import apart_links, decide, reference
from .state import Memory, Near, Told


@dataclass
class Neighbourhood:
    """Neighbours' latest states, rows in ascending MAP id (the order the batch simulator sums in)."""

    q: np.ndarray          # (n, 3) positions (m)
    p: np.ndarray          # (n, 3) velocities (m/s)
    n_users: np.ndarray    # (n,) N_u^j
    achieved: list[int]    # achieved-goal masks
    told: list[Told]       # mode, goal and bridge each one stated
    seen: list[tuple[tuple[int, int], ...]] = field(default_factory=list)    # roles each one heard of (vacancy.py)
    lost: list[tuple[tuple[float, float], ...]] = field(default_factory=list)  # keys each one knows lost
    short: list[tuple[tuple[int, int], ...]] = field(default_factory=list)     # roles each one found short

    @classmethod
    def empty(cls) -> 'Neighbourhood':
        return cls(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), [], [])


def agent_step(mem: Memory, agent_id: int, q: np.ndarray, p_vel: np.ndarray, n_users: int, cluster_coverage: np.ndarray,
               nbrs: Neighbourhood, clusters: ClusterMap, params: FlockParams, step: int = 0) -> tuple[np.ndarray, Memory]:
    """Algorithm 1 lines 3-6 for one MAP at step k: gossip, mode switch (Alg. 2), control input (eq. 9)."""
    mem = decide(mem, agent_id, n_users, cluster_coverage, q, nbrs.achieved, clusters, params, step,
                 (nbrs.seen, nbrs.lost, nbrs.short), Near(nbrs.q, nbrs.told))
    ref = reference(mem, agent_id, q, nbrs.q, nbrs.told, clusters, params)
    owner = np.zeros(len(nbrs.q), dtype=np.intp)
    u = control_input(q[None, :], p_vel[None, :], np.array([float(n_users)]), np.array([ref.mode]),
                      ref.target[None, :], ref.q1[None, :], ref.q2[None, :], owner, nbrs.q, nbrs.p,
                      np.asarray(nbrs.n_users, dtype=float), params,
                      np.array(apart_links(mem, nbrs.told, params), dtype=np.intp), ref.velocity[None])
    return u[0], mem
