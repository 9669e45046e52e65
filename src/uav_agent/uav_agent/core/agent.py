"""One MAP's whole step, written once: the agent node runs it for its MAP, the batch simulator for every MAP.

What a MAP hears of its neighbours (`Said`, gathered into a `Neighbourhood`) and its own sensing go in;
`plan` decides its mode and role and what eq. 9's terms aim at; `control_input` (control.py) turns that
into u_i. The batch simulator sums eq. 9 for all MAPs at once with the same function, fed the same rows.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Sequence

import numpy as np

from .ablation import on
from .clusters import ClusterMap
from .control import control_input
from .links import Inbox, Links
from .params import FlockParams
from .policies import decide, links, reference
from .state import Memory, Near, Reference, Told


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

    @classmethod
    def empty(cls) -> 'Neighbourhood':
        return cls(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), [], [])

    @classmethod
    def hearing(cls, q: np.ndarray, p: np.ndarray, n_users: np.ndarray, said: Sequence[Said]) -> 'Neighbourhood':
        """The neighbourhood of what each neighbour said, rows alike: the one place the gossip is gathered."""
        return cls(np.asarray(q, dtype=float).reshape(-1, 3), np.asarray(p, dtype=float).reshape(-1, 3),
                   np.asarray(n_users, dtype=float), [s.achieved for s in said], [s.told for s in said])


class Heard(NamedTuple):
    """One neighbour state as a MAP holds it under a channel (links.Inbox): q, p and N_u of its step, and what
    it said then."""

    q: np.ndarray
    p: np.ndarray
    n_users: float
    said: Said


def _placed(held: Sequence[tuple[int, int, Heard]], dt: float, here: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where each held state's sender is now (rule 'predict': flown on at its velocity then for its age), and
    how far that is from `here`."""
    q = np.array([h.q for _, _, h in held], dtype=float).reshape(-1, 3)
    if on('predict') and len(held):
        q = q + np.array([age * dt for _, age, _ in held])[:, None] * np.array([h.p for _, _, h in held])
    return q, np.linalg.norm(q - here, axis=1)


def heard_from(held: Sequence[tuple[int, int, Heard]], dt: float, here: np.ndarray, r: float) -> Neighbourhood:
    """The neighbourhood of the states a MAP holds under a channel ((id, age in steps, state), ascending id,
    as links.Inbox.usable gives them), for a MAP at `here`.

    A state `age` steps old stands for where its sender is now, flown on at its velocity then (rule
    'predict'); one whose sender is so placed beyond r is taken for gone (rule 'gone'): out of range, its
    messages stop as lost ones do, and its old place would pull the MAP towards where it no longer is.
    """
    return _within(held, *_placed(held, dt, here), r)


def _within(held: Sequence[tuple[int, int, Heard]], q: np.ndarray, dist: np.ndarray, r: float) -> Neighbourhood:
    """heard_from's neighbourhood from where the held states' senders are placed and how far they are."""
    states = [h for _, _, h in held]
    keep = dist <= r if on('gone') else np.ones(len(states), dtype=bool)
    return Neighbourhood.hearing(q[keep], np.array([h.p for h in states]).reshape(-1, 3)[keep],
                                 np.array([h.n_users for h in states])[keep], [h.said for h, k in zip(states, keep) if k])


PASSED_ON = 8  # neighbour states a MAP passes on in its own message, its nearest (rule 'hearsay'; AgentState.passed_on)


class Passed(NamedTuple):
    """A neighbour's state as another MAP passes it on: whose, of which step, and the state."""

    id: int
    step: int
    heard: Heard


class Hearing(Inbox[Heard]):
    """What one MAP holds of its neighbours under a channel that is not the paper's: their states (links.Inbox),
    and the states it passes on to its neighbours (rule 'hearsay').

    The agent node holds one for its MAP, the batch simulator one per MAP.
    """

    def __init__(self, channel: Links, me: int, hearsay: bool = True) -> None:
        super().__init__(channel)
        self.me = me
        self.hearsay = hearsay  # whether this MAP passes on what it holds (policies.hearsay)
        self.passed: list[Passed] = []  # what this MAP's next state message passes on (neighbourhood)

    def hear(self, k: int, ids: list[int], states: list[Heard], passed: Sequence[Sequence[Passed]]) -> None:
        """The state messages of step k the channel delivered: each sender's state, then what it passed on
        (rows alike). The batch simulator and the agent node both take what they heard here."""
        self.receive(k, ids, states)
        for each in passed:
            self.hear_passed(k, each)

    def hear_passed(self, k: int, passed: Sequence[Passed]) -> None:
        """Rule 'hearsay': the states a neighbour passed on in its message of step k, heard with it.

        Under bursts a link stays silent for seconds while the MAPs at both ends hear a third: what that third
        passes on keeps each end's neighbour from vanishing, and with it the forces that hold the formation
        (docs/links.md). A state passed on is as old as its own step says; its latency runs from step k, when
        the message that carried it was sent. One not newer than what the MAP holds is ignored.
        """
        if not on('hearsay'):
            return
        for j, at, heard in passed:
            if j != self.me and at > self.newest(j):
                self.passed_on(k, j, at, heard)

    def neighbourhood(self, k: int, dt: float, here: np.ndarray, r: float) -> Neighbourhood:
        """heard_from of the states usable at step k; the PASSED_ON nearest of them within r are what the MAP
        passes on next."""
        held = self.usable(k)
        q, dist = _placed(held, dt, here)
        hood = _within(held, q, dist, r)
        if self.hearsay:
            nearest = sorted((n for n in range(len(held)) if dist[n] <= r), key=lambda n: (dist[n], held[n][0]))
            self.passed = [Passed(held[n][0], k - held[n][1], held[n][2])
                           for n in sorted(nearest[:PASSED_ON], key=lambda n: held[n][0])]
        return hood


class Plan(NamedTuple):
    """One MAP's decision of step k: its memory after it, what eq. 9's goal term aims at, and what each
    neighbour's link is to the flocking terms (state.RELATED, APART or PASSING), rows as the neighbours'."""

    memory: Memory
    reference: Reference
    links: list[int]


def plan(mem: Memory, agent_id: int, q: np.ndarray, n_users: int, cluster_coverage: np.ndarray, nbrs: Neighbourhood,
         clusters: ClusterMap, params: FlockParams, step: int = 0) -> Plan:
    """Algorithm 1 lines 3-5 for one MAP at step k: gossip, mode switch (Alg. 2), the goal term's reference."""
    mem = decide(mem, agent_id, n_users, cluster_coverage, q, nbrs.achieved, clusters, params, step,
                 Near(nbrs.q, nbrs.told))
    ref = reference(mem, agent_id, q, nbrs.q, nbrs.told, clusters, params)
    return Plan(mem, ref, links(mem, nbrs.told, params))


def agent_step(mem: Memory, agent_id: int, q: np.ndarray, p_vel: np.ndarray, n_users: int, cluster_coverage: np.ndarray,
               nbrs: Neighbourhood, clusters: ClusterMap, params: FlockParams, step: int = 0,
               traffic: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, Memory]:
    """Algorithm 1 lines 3-6 for one MAP at step k: its plan, then its control input (eq. 9). traffic: the
    positions and velocities its traffic receiver took in (vehicle.traffic), None without one."""
    mem, ref, links = plan(mem, agent_id, q, n_users, cluster_coverage, nbrs, clusters, params, step)
    owner = np.zeros(len(nbrs.q), dtype=np.intp)
    seen = None if traffic is None else (np.zeros(len(traffic[0]), dtype=np.intp), *traffic)
    u = control_input(q[None, :], p_vel[None, :], np.array([float(n_users)]), np.array([ref.mode]),
                      ref.target[None, :], ref.q1[None, :], ref.q2[None, :], owner, nbrs.q, nbrs.p,
                      np.asarray(nbrs.n_users, dtype=float), params, np.array(links, dtype=np.intp),
                      ref.velocity[None], seen)
    return u[0], mem
