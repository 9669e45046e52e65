"""One MAP's whole step, written once: the agent node runs it for its MAP, the batch simulator for every MAP.

What a MAP hears of its neighbours (`Said`, gathered into a `Neighbourhood` by its ear, ear.py) and its own
sensing go in; `plan` decides its mode and role and what eq. 9's terms aim at; `control_input` (control.py)
turns that into u_i. The batch simulator sums eq. 9 for all MAPs at once with the same function, fed the same rows.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Sequence

import numpy as np

from .clusters import ClusterMap, segment_distance
from .control import control_input
from .params import FlockParams
from .policies import decide, links, needed, reference
from .safety import held_next
from .state import M1, Memory, Near, Reference, Told


class Said(NamedTuple):
    """What a MAP's state message of step k tells its neighbours besides q, p and N_u: the goals it knows
    achieved (a mask), and its role with what its allocation adds (Told)."""

    achieved: int
    told: Told

    @classmethod
    def of(cls, mem: Memory) -> 'Said':
        """What a MAP with this memory says, as its state message carries it (agent_node.publish_state)."""
        return cls(mem.achieved, Told.of(mem))


@dataclass
class Neighbourhood:
    """Neighbours' latest states, rows in ascending MAP id (the order the batch simulator sums in)."""

    q: np.ndarray          # (n, 3) positions (m)
    p: np.ndarray          # (n, 3) velocities (m/s)
    n_users: np.ndarray    # (n,) N_u^j
    achieved: list[int]    # achieved-goal masks
    told: list[Told]       # what each one stated of its role, and its allocation's block
    # (n,) how old each state is (s): 0 under the paper's channel; under another (docs/links.md) the time since the
    # step it was sent at, which the safety filter's link rows allow for (control.control_input). None: all 0.
    age: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.age is None:
            self.age = np.zeros(len(self.q))

    @classmethod
    def empty(cls) -> 'Neighbourhood':
        return cls(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), [], [])

    @classmethod
    def hearing(cls, q: np.ndarray, p: np.ndarray, n_users: np.ndarray, said: Sequence[Said],
                age: np.ndarray | None = None) -> 'Neighbourhood':
        """The neighbourhood of what each neighbour said, rows alike: the one place the gossip is gathered."""
        return cls(np.asarray(q, dtype=float).reshape(-1, 3), np.asarray(p, dtype=float).reshape(-1, 3),
                   np.asarray(n_users, dtype=float), [s.achieved for s in said], [s.told for s in said],
                   None if age is None else np.asarray(age, dtype=float))


class Plan(NamedTuple):
    """One MAP's decision of step k: its memory after it, what eq. 9's goal term aims at, what each
    neighbour's link is to the flocking terms (state.RELATED, APART, PASSING or INLINE) and who keeps it if the
    network needs it kept (the safety filter's rule 'links': state.UNKEPT, SHARED, ALONE), rows as the neighbours'."""

    memory: Memory
    reference: Reference
    links: list[int]
    needed: list[int]


def plan(mem: Memory, agent_id: int, q: np.ndarray, n_users: int, cluster_coverage: np.ndarray, nbrs: Neighbourhood,
         clusters: ClusterMap, params: FlockParams, step: int = 0, held: int = 0) -> Plan:
    """Algorithm 1 lines 3-5 for one MAP at step k: gossip, mode switch (Alg. 2), the goal term's reference; held,
    the safety filter's liveness count (Step.held)."""
    mem = decide(mem, agent_id, n_users, cluster_coverage, q, nbrs.achieved, clusters, params, step,
                 Near(nbrs.q, nbrs.told))
    ref = reference(mem, agent_id, q, nbrs.q, nbrs.told, clusters, params)
    return Plan(mem, ref, links(mem, nbrs.told, params), needed(mem, nbrs.told, params, held < 0))


def off_goal(q: np.ndarray, ref: Reference) -> float:
    """How far (m, in the plane) a MAP is from where its goal term aims: q^r (eq. 12), or a relay's piece of its
    edge q_1^r-q_2^r (eq. 13)."""
    if ref.mode != M1:
        return float(np.hypot(*(np.asarray(q, dtype=float)[:2] - ref.target[:2])))
    return segment_distance(q, ref.q1[:2], ref.q2[:2])


def after_filter(held: int, flags: int, q: np.ndarray, ref: Reference, params: FlockParams) -> tuple[int, int]:
    """A MAP's liveness count and flags once its command is filtered (safety.held_next, rule 'release'): what the
    agent node and the batch simulator both carry from step to step. Nothing changes without the safety filter."""
    if params.safety != 'filter':
        return held, flags
    held, bits = held_next(held, flags, off_goal(q, ref), params)
    return held, flags | bits


class Step(NamedTuple):
    """One MAP's step: its command u_i, its memory after it, what the safety filter did to u_i (safety.RELAXED,
    HELD, AWAY, RELEASED bits) and its liveness count for the next step (safety.held_next; 0 without the filter)."""

    u: np.ndarray
    memory: Memory
    flags: int
    held: int


def agent_step(mem: Memory, agent_id: int, q: np.ndarray, p_vel: np.ndarray, n_users: int, cluster_coverage: np.ndarray,
               nbrs: Neighbourhood, clusters: ClusterMap, params: FlockParams, step: int = 0,
               traffic: tuple[np.ndarray, np.ndarray] | None = None, held: int = 0) -> Step:
    """Algorithm 1 lines 3-6 for one MAP at step k: its plan, then its control input (eq. 9), and what the safety
    filter did to it (safety.RELAXED, HELD bits). traffic: the positions and velocities its traffic receiver took
    in (vehicle.traffic), None without one; held: its liveness count from the step before (Step.held)."""
    mem, ref, links, keep = plan(mem, agent_id, q, n_users, cluster_coverage, nbrs, clusters, params, step, held)
    owner = np.zeros(len(nbrs.q), dtype=np.intp)
    seen = None if traffic is None else (np.zeros(len(traffic[0]), dtype=np.intp), *traffic)
    u, flags, _ = control_input(q[None, :], p_vel[None, :], np.array([float(n_users)]), np.array([ref.mode]),
                      ref.target[None, :], ref.q1[None, :], ref.q2[None, :], owner, nbrs.q, nbrs.p,
                      np.asarray(nbrs.n_users, dtype=float), params, np.array(links, dtype=np.intp),
                      ref.velocity[None], seen, np.array(keep, dtype=np.int8), nbrs.age)
    held, did = after_filter(held, int(flags[0]), q, ref, params)
    return Step(u[0], mem, did, held)
