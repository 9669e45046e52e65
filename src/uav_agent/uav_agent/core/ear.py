"""What a MAP hears of its neighbours: the one road from the state messages of step k that reached it to the
neighbourhood its step decides from.

The batch simulator, the agent node in both sync modes and the world's records all hear through `hear`: the
channel (links.deliver) decides for each state that reached a MAP whether it is heard and from which step it
may be used, and the MAP's `Ear` holds what it heard, and what a neighbour passed on with it, until its
`neighbourhood`. A new channel key or delivery model changes links.py alone; a new rule of hearing, this
module alone (docs/links.md, "Adding a channel key").
"""
from __future__ import annotations

from typing import Any, NamedTuple, Optional, Sequence

import numpy as np

from .ablation import on
from .agent import Neighbourhood, Said
from .links import LOST, Inbox, Links, deliver

PASSED_ON = 8  # neighbour states a MAP passes on in its own message, its nearest (rule 'hearsay'; AgentState.passed_on)


class Heard(NamedTuple):
    """One neighbour state as a MAP holds it: q, p and N_u of its step, and what it said then."""

    q: np.ndarray
    p: np.ndarray
    n_users: float
    said: Said


class Passed(NamedTuple):
    """A neighbour's state as another MAP passes it on: whose, of which step, and the state."""

    id: int
    step: int
    heard: Heard


class Sent(NamedTuple):
    """One neighbour's state message of step k as it reached a MAP: whose, its state, and the states it passed
    on (rule 'hearsay')."""

    id: int
    heard: Heard
    passed: Sequence[Passed] = ()


class Ear:
    """What one MAP holds of its neighbours' states, and what it passes on of them in its next message.

    Under the paper's channel it holds the states of the step it last heard; under any other, each heard state
    from the step it may be used at until ttl steps after its own (links.Inbox). The agent node holds one for
    its MAP, the batch simulator and the world's records one per MAP.
    """

    def __init__(self, channel: Links, seed: int, me: int, hearsay: bool = True) -> None:
        self.channel, self.seed, self.me = channel, seed, me
        self.hearsay = hearsay  # whether this MAP passes on what it holds (policies.hearsay)
        self.inbox: Optional[Inbox[Any]] = None if channel.perfect else Inbox(channel)
        self.now: tuple[int, list[Heard]] = (-1, [])  # the paper's channel: the states of the step last heard
        self.passed: list[Passed] = []  # what this MAP's next state message passes on (neighbourhood)

    def take(self, k: int, sent: Sequence[Sent], ready: np.ndarray) -> None:
        """The messages of step k that reached the MAP, each heard from step `ready` on (links.deliver; LOST:
        not heard); what a heard one passed on is heard with it, its latency running from step k."""
        if self.inbox is None:
            self.now = (k, [m.heard for m in sent])
            return
        heard = [(m, int(at)) for m, at in zip(sent, ready.tolist()) if at != LOST]
        self.inbox.receive(k, [m.id for m, _ in heard], [m.heard for m, _ in heard], [at for _, at in heard])
        if on('hearsay'):
            for m, at in heard:
                self.hear_passed(at, m.passed)

    def hear_passed(self, ready: int, passed: Sequence[Passed]) -> None:
        """Rule 'hearsay': the states a neighbour passed on in a message heard from step `ready`.

        Under bursts a link stays silent for seconds while the MAPs at both ends hear a third: what that third
        passes on keeps each end's neighbour from vanishing, and with it the forces that hold the formation
        (docs/links.md). A state passed on is as old as its own step says; it may be used when the message that
        carried it may. One not newer than what the MAP holds is ignored.
        """
        assert self.inbox is not None
        for j, at, heard in passed:
            if j != self.me and at > self.inbox.newest(j):
                self.inbox.passed_on(ready, j, at, heard)

    def neighbourhood(self, k: int, dt: float, here: np.ndarray, r: float) -> Neighbourhood:
        """The neighbourhood the MAP at `here` decides from at step k: under the paper's channel the states of
        step k; under another, heard_from of the states usable at k, the PASSED_ON nearest of them within r
        being what the MAP passes on next."""
        if self.inbox is None:
            at, states = self.now
            states = states if at == k else []
            return Neighbourhood.hearing(np.array([h.q for h in states]).reshape(-1, 3),
                                         np.array([h.p for h in states]).reshape(-1, 3),
                                         np.array([h.n_users for h in states], dtype=float), [h.said for h in states])
        held = self.inbox.usable(k)
        q, dist = _placed(held, dt, here)
        hood = _within(held, q, dist, r, dt)
        if self.hearsay:
            nearest = sorted((n for n in range(len(held)) if dist[n] <= r), key=lambda n: (dist[n], held[n][0]))
            self.passed = [Passed(held[n][0], k - held[n][1], held[n][2])
                           for n in sorted(nearest[:PASSED_ON], key=lambda n: held[n][0])]
        return hood

    def oldest(self, k: int) -> int:
        """The age in steps of the oldest state usable at step k (0 under the paper's channel)."""
        return max((age for _, age, _ in self.inbox.usable(k)), default=0) if self.inbox is not None else 0


def hear(ears: Sequence[Ear], k: int, here: np.ndarray, sent: Sequence[Sequence[Sent]], r: float) -> list[np.ndarray]:
    """The one road: every state of step k that reached each MAP (ears[n] at here[n], sent[n]) through the
    channel's decision (links.deliver, one call for all), and each ear taking what it heard. Returns, per
    MAP, whether each of its messages was heard."""
    counts = [len(m) for m in sent]
    flat = [m for each in sent for m in each]
    rx = np.repeat(np.array([e.me for e in ears], dtype=np.int64), counts)
    q_rx = np.repeat(np.asarray(here, dtype=float).reshape(-1, 3), counts, axis=0)
    tx = np.array([m.id for m in flat], dtype=np.int64)
    q_tx = np.array([m.heard.q for m in flat], dtype=float).reshape(-1, 3)
    channel = ears[0].channel if ears else Links()
    ready = deliver(channel, ears[0].seed if ears else 0, k, rx, tx, q_rx, q_tx, r)
    out, at = [], 0
    for ear, each, n in zip(ears, sent, counts):
        ear.take(k, each, ready[at:at + n])
        out.append(ready[at:at + n] != LOST)
        at += n
    return out


def heard_from(held: Sequence[tuple[int, int, Heard]], dt: float, here: np.ndarray, r: float) -> Neighbourhood:
    """The neighbourhood of the states a MAP holds under a channel ((id, age in steps, state), ascending id,
    as links.Inbox.usable gives them), for a MAP at `here`.

    A state `age` steps old stands for where its sender is now, flown on at its velocity then (rule
    'predict'); one whose sender is so placed beyond r is taken for gone (rule 'gone'): out of range, its
    messages stop as lost ones do, and its old place would pull the MAP towards where it no longer is.
    """
    return _within(held, *_placed(held, dt, here), r, dt)


def _placed(held: Sequence[tuple[int, int, Heard]], dt: float, here: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where each held state's sender is now (rule 'predict': flown on at its velocity then for its age), and
    how far that is from `here`."""
    q = np.array([h.q for _, _, h in held], dtype=float).reshape(-1, 3)
    if on('predict') and len(held):
        q = q + np.array([age * dt for _, age, _ in held])[:, None] * np.array([h.p for _, _, h in held])
    return q, np.linalg.norm(q - here, axis=1)


def _within(held: Sequence[tuple[int, int, Heard]], q: np.ndarray, dist: np.ndarray, r: float,
            dt: float) -> Neighbourhood:
    """heard_from's neighbourhood from where the held states' senders are placed and how far they are, with
    each state's age (s)."""
    states = [h for _, _, h in held]
    keep = dist <= r if on('gone') else np.ones(len(states), dtype=bool)
    age = np.array([a * dt for _, a, _ in held], dtype=float)
    return Neighbourhood.hearing(q[keep], np.array([h.p for h in states]).reshape(-1, 3)[keep],
                                 np.array([h.n_users for h in states])[keep], [h.said for h, k in zip(states, keep) if k],
                                 age[keep])
