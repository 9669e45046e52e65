"""What a MAP carries from step to step, what it tells its neighbours of its role, and what its goal term
aims at (Algorithm 2's M_i, g_c^i and bridge; eqs. 12-13's references)."""
from __future__ import annotations

from typing import Any, NamedTuple, Optional, Sequence

import numpy as np

from .clusters import NO_GOAL, ClusterMap, Edge

M0, M1, M2 = 0, 1, 2  # dynamic, connectivity, static (Section IV-A)
# What a neighbour link is to the flocking terms (control.flocking_terms): both roles related (all of eq. 10),
# unrelated (repulsion within d only), one of the two on its way to a new role (repulsion within d/2 only), or
# fellow relays of one chain on a lagged vehicle (all of eq. 10 along their edge only: rule 'inline').
RELATED, APART, PASSING, INLINE = 0, 1, 2, 3
# Who keeps a link the network needs against the nominal (the safety filter's rule 'links', Allocation.needed): no
# one (the link is not needed, or the other end keeps it alone), both ends, each its share (safety.opening_share), or
# this MAP alone, the other end flying free of it.
UNKEPT, SHARED, ALONE = 0, 1, 2


class Memory(NamedTuple):
    """What a MAP carries from step to step: its mode M_i, goal g_c^i, known achieved goals and bridge
    (Algorithm 2), and what its allocation keeps of its own (own: None, or a record the allocation defines,
    e.g. allocations.demand.memory.Own)."""

    mode: int = M0
    goal: int = NO_GOAL
    achieved: int = 0
    bridge: Optional[Edge] = None
    own: Any = None


class Told(NamedTuple):
    """What a neighbour's state message says of its role: mode, goal and bridge (as of its last step), and
    what its allocation adds to the message (block: None, or what `own.said()` returns; read by the
    allocation alone, by attribute, so the same values from a message or from a simulated MAP read alike)."""

    mode: int
    goal: int
    bridge: Optional[Edge]
    block: Any = None

    @classmethod
    def of(cls, mem: Memory) -> 'Told':
        """What a MAP's own state message says of its role, as its neighbours read it."""
        said = getattr(mem.own, 'said', None)
        return cls(mem.mode, mem.goal, mem.bridge, said() if said is not None else None)


class Near(NamedTuple):
    """The radio neighbours as a MAP's discrete update sees them: positions (n, 3) in m, and the roles they
    stated, rows alike."""

    q: np.ndarray
    told: Sequence[Told]


NOBODY = Near(np.zeros((0, 3)), ())


class Reference(NamedTuple):
    """What eq. 9's goal term aims at: q^r (M0/M2), q_1^r and q_2^r (M1), the mode that picks between
    them, and the velocities the damping of eqs. 12-13 matches (rows: q^r, q_1^r, q_2^r)."""

    target: np.ndarray
    q1: np.ndarray
    q2: np.ndarray
    mode: int
    velocity: np.ndarray  # (3, 3)


def aim(mem: Memory, q: np.ndarray, clusters: ClusterMap) -> tuple[np.ndarray, np.ndarray]:
    """q^r of eq. 12 and its velocity: the goal cluster's centre at flight height, moving as the cluster
    does; where the MAP is, at rest, when it has no goal (no cluster exists)."""
    if mem.goal != NO_GOAL:
        return clusters.targets[mem.goal], clusters.velocities[mem.goal]
    return np.asarray(q, dtype=float), np.zeros(3)


def hold(mem: Memory, here: np.ndarray, v: np.ndarray) -> Reference:
    """The reference of a MAP with nothing to bridge: its goal (eq. 12); M1 without a bridge holds like M2."""
    return Reference(here, here, here, (M2 if mem.mode == M1 else mem.mode), np.array([v, v, v]))
