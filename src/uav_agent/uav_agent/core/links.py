"""The radio between MAPs (a scenario's `links:` section, docs/scenarios.md): which neighbour states a MAP
hears, and from when it may use them.

The paper's neighbours N_i = {j : ||q_i - q_j|| <= r} hear each other perfectly and at once (`delivery:
disc`, the default). A channel may lose a state by distance (`alpha`: the paper's alpha_{z1,z0} of eq. 3
as the delivery probability, z0 = r), lose it on top of that (`loss`, in bursts of mean length `burst`
steps from a Gilbert-Elliott process), and deliver it `latency` steps late; a MAP uses each neighbour's
last state heard for `ttl` steps.

Every decision is the receiving MAP's, and a pure function of the run seed, the step k the state belongs
to, the two ids and the two positions at k (its own, and the one the message carries): the batch simulator
and the agent nodes make the same ones, so lockstep `up` equals `sim` byte for byte under any channel.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from functools import cache
from importlib.metadata import entry_points
from typing import Any, Callable, Generic, Protocol, TypeVar

import numpy as np

from .checks import number
from .potentials import bump

COUPLED = 1e-6  # the burst process is run from far enough back that two starts disagree at k this rarely
# Streams of draws, so that the delivery draw and the loss draw of one message are independent.
_DELIVERY, _LOSS = 1, 2
_M64 = np.uint64(0xFFFFFFFFFFFFFFFF)


@dataclass(frozen=True)
class Links:
    """The channel between MAPs. Units: steps for burst, latency and ttl; fractions for z1 (of r) and loss."""

    delivery: str = 'disc'  # 'disc': every state within r is heard; 'alpha': with probability alpha(||q_i - q_j||)
    z1: float = 0.8         # where alpha's fall begins, as a fraction of r (it ends at r)
    loss: float = 0.0       # mean share of the states lost on top of delivery, in [0, 1)
    burst: float = 1.0      # mean length of a run of lost states (steps); 1: each lost independently
    latency: int = 0        # steps from a state's step to the first step it may be used at
    ttl: int = 10           # steps after its step that a neighbour's last state heard is still used

    @property
    def perfect(self) -> bool:
        """The paper's channel: every neighbour within r heard at once."""
        return self.delivery == 'disc' and self.loss == 0.0 and self.latency == 0

    def as_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


class Delivery(Protocol):
    """A delivery model (`links.delivery`): how likely a state sent over a distance is delivered, before `loss`.

    Registered by name in DELIVERIES, or from another package by an entry point in the group ENTRY_POINTS
    (`name = module:Class`): a new model is one module, which `sim`, the agent nodes and the world's records
    all find by its name (docs/links.md, "Adding a delivery model")."""

    def probability(self, links: Links, dist: np.ndarray, r: float) -> np.ndarray:
        """The probability that a state sent over each distance (m) is delivered, for neighbours within r."""

    def reach(self, links: Links, r: float) -> float:
        """The longest link (m) that delivers USABLE of its states (FlockParams.reach)."""

    def describe(self, links: Links) -> str:
        """The model in words, as a run's header says it."""


class Disc:
    """The paper's channel: every state within r."""

    def probability(self, links: Links, dist: np.ndarray, r: float) -> np.ndarray:
        return np.where(np.asarray(dist, dtype=float) <= r, 1.0, 0.0)

    def reach(self, links: Links, r: float) -> float:
        return r

    def describe(self, links: Links) -> str:
        return 'every state within r'


class Alpha:
    """The paper's alpha_{z1 r, r} of eq. 3 as the delivery probability: 1 up to z1 r, a half cosine to 0 at r."""

    def probability(self, links: Links, dist: np.ndarray, r: float) -> np.ndarray:
        return bump(np.asarray(dist, dtype=float), links.z1 * r, r)

    def reach(self, links: Links, r: float) -> float:
        return links.z1 * r + (1.0 - links.z1) * r * math.acos(2.0 * USABLE - 1.0) / math.pi

    def describe(self, links: Links) -> str:
        return f"delivered with the paper's alpha (falling from {links.z1:g} r to r)"


DELIVERIES: dict[str, Delivery] = {'disc': Disc(), 'alpha': Alpha()}
ENTRY_POINTS = 'uav_flock.deliveries'  # the entry point group other packages register delivery models in


@cache
def deliveries() -> dict[str, Delivery]:
    """Every delivery model by name: DELIVERIES, then those other packages register (ENTRY_POINTS)."""
    found = dict(DELIVERIES)
    for point in entry_points(group=ENTRY_POINTS):
        if point.name not in found:
            found[point.name] = point.load()()
    return found


def describe(links: Links) -> str:
    """The channel in a line, as a run's header says it."""
    said = [deliveries()[links.delivery].describe(links)]
    if links.loss:
        said.append(f'{100 * links.loss:g} % lost on top' + (f' in bursts of {links.burst:g} steps' if links.burst > 1 else ''))
    if links.latency:
        said.append(f'{links.latency} step{"s" if links.latency > 1 else ""} late')
    said.append(f'a state used for {links.ttl} steps')
    return ', '.join(said)


def check(links: Links, where: Callable[[str], str] = lambda name: f'links.{name}') -> Links:
    """The channel with its numbers as floats and whole steps as ints; ValueError, naming the key as
    `where(name)` does, for a channel no run can use."""
    if links.delivery not in deliveries():
        raise ValueError(f'{where("delivery")}: must be one of {", ".join(deliveries())}, got {links.delivery!r}')
    for name in ('z1', 'loss'):  # fractions below 1: at 1, alpha has no fall, or nothing is ever heard
        value = number(getattr(links, name), where(name), low=0.0, high=1.0)
        if value >= 1.0:
            raise ValueError(f'{where(name)}: must be below 1, got {value!r}')
    links = Links(links.delivery, float(links.z1), float(links.loss), number(links.burst, where('burst'), low=1.0),
                  number(links.latency, where('latency'), low=0, integer=True),
                  number(links.ttl, where('ttl'), low=0, integer=True))
    if links.ttl < links.latency:
        raise ValueError(f'{where("ttl")}: must be at least {where("latency")} ({links.latency}) or no state '
                         f'is ever used, got {links.ttl}')
    if links.burst > 1.0 and links.burst * (1.0 - links.loss) < 1.0:
        raise ValueError(f'{where("burst")}: at loss {links.loss:g} independent losses already come in runs of '
                         f'{1.0 / (1.0 - links.loss):.3g} steps on average; use 1 or at least that, got {links.burst:g}')
    return links


LOST = -1  # deliver's step for a state that is not heard


def deliver(links: Links, seed: int, k: int, rx: np.ndarray, tx: np.ndarray, q_rx: np.ndarray, q_tx: np.ndarray,
            r: float) -> np.ndarray:
    """The channel's one decision (ear.hear calls it for every reader): for each state of step k that tx sent
    and that reached rx, the two at q_rx and q_tx at step k (rows alike; tx within r of rx, as the world lists
    neighbours), the first step rx may use it at, or LOST. A channel key that changes whether or when a state
    is heard changes this function (and `Links`) alone."""
    rx = np.asarray(rx, dtype=np.int64)
    if links.perfect:
        return np.full(len(rx), k, dtype=np.int64)
    return np.where(heard(links, seed, k, rx, tx, q_rx, q_tx, r), k + links.latency, LOST).astype(np.int64)


def heard(links: Links, seed: int, k: int, rx: np.ndarray, tx: np.ndarray, q_rx: np.ndarray, q_tx: np.ndarray,
          r: float) -> np.ndarray:
    """Whether each receiver rx hears the state of step k that tx sent (deliver, before its latency)."""
    ok = np.ones(len(rx), dtype=bool)
    if links.delivery != 'disc':  # disc delivers every state within r, which is all the world lists
        dist = np.linalg.norm(np.asarray(q_tx, dtype=float) - np.asarray(q_rx, dtype=float), axis=-1)
        ok &= draws(seed, _DELIVERY, np.full(len(rx), k), rx, tx) < delivery(links, dist, r)
    if links.loss > 0.0:
        ok &= ~lost(links, seed, k, rx, tx)
    return ok


def delivery(links: Links, dist: np.ndarray, r: float) -> np.ndarray:
    """The probability that a state sent over each distance (m) is delivered, before `loss`, by the channel's
    delivery model: 1 within r under disc, the paper's alpha_{z1 r, r} (eq. 3) under alpha."""
    return deliveries()[links.delivery].probability(links, np.asarray(dist, dtype=float), r)


USABLE = 0.5  # a link that delivers at least this share of the states sent over it is in the usable graph


def reach(links: Links, r: float) -> float:
    """The longest link (m) that delivers USABLE of its states (before `loss`): r under disc; under alpha,
    where its half cosine falls to USABLE. 0 stands for r (FlockParams.reach)."""
    if links.delivery == 'disc':
        return 0.0
    return deliveries()[links.delivery].reach(links, r)


def hush(links: Links) -> int:
    """Steps a neighbour may stay silent and still be there (FlockParams.hush): 0 under the paper's channel,
    where silence is absence; otherwise its ttl and three mean bursts, past which a run of losses that long
    is rare (a burst outlasts n of its means with probability about e^-n)."""
    return 0 if links.perfect else int(links.ttl + math.ceil(3.0 * links.burst))


def lost(links: Links, seed: int, k: int, rx: np.ndarray, tx: np.ndarray) -> np.ndarray:
    """Whether the loss process of each link (tx -> rx) is in its lossy state at step k.

    Independent draws when burst is 1. Otherwise a two-state Gilbert-Elliott chain per link: the lossy state
    lasts `burst` steps on average and holds a share `loss` of the time. Its state at k is found by running
    the chain, on the link's own draws of each step, from both states `window` steps back: the two runs meet
    (and then agree) with probability 1 - COUPLED, so the state at k is the one chain's, whoever asks when.
    """
    n = len(rx)
    if links.burst <= 1.0:
        return draws(seed, _LOSS, np.full(n, k), rx, tx) < links.loss
    leave = 1.0 / links.burst                                   # P(lossy -> clear)
    enter = links.loss / (links.burst * (1.0 - links.loss))     # P(clear -> lossy), for a share `loss` lossy
    back = window(links)
    u = draws(seed, _LOSS, np.arange(k - back + 1, k + 1)[None, :].repeat(n, 0), rx[:, None], tx[:, None])
    state = np.zeros(n, dtype=bool)  # from the clear state; the run from the lossy one meets it (COUPLED)
    for t in range(back):
        state = u[:, t] < np.where(state, 1.0 - leave, enter)
    return state


def window(links: Links) -> int:
    """Steps the burst chain is run for: two runs from opposite states fail to meet that long with
    probability COUPLED at most (they meet at a step whose draw sends both the same way)."""
    meet = 1.0 / links.burst + links.loss / (links.burst * (1.0 - links.loss))
    return max(int(math.ceil(math.log(COUPLED) / math.log1p(-min(meet, 1.0 - 1e-12)))), 1)


def draws(seed: int, stream: int, k: np.ndarray, rx: np.ndarray, tx: np.ndarray) -> np.ndarray:
    """Uniform draws in [0, 1), one per (seed, stream, k, rx, tx), each from that tuple alone.

    A counter-based draw (splitmix64's finaliser over the tuple): numpy's generators draw sequences, and a
    MAP must draw for any step and link in any order and get what every other reader of that step gets.
    """
    h = np.full(np.broadcast(k, rx, tx).shape, np.uint64(seed & 0xFFFFFFFFFFFFFFFF), dtype=np.uint64)
    for part in (stream, k, rx, tx):
        h = _mix(h ^ _mix(np.asarray(part).astype(np.int64).astype(np.uint64) + np.uint64(0x9E3779B97F4A7C15)))
    return (h >> np.uint64(11)).astype(np.float64) * (1.0 / (1 << 53))


def _mix(x: np.ndarray) -> np.ndarray:
    with np.errstate(over='ignore'):
        x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return (x ^ (x >> np.uint64(31))) & _M64


P = TypeVar('P')


class Inbox(Generic[P]):
    """What one MAP holds of its neighbours' states: each heard state, from the step it may be used at (deliver)
    until ttl steps after its own step (ear.Ear holds one under a channel that is not the paper's)."""

    def __init__(self, links: Links) -> None:
        self.links = links
        # neighbour id -> (first step it may be used at, step of the state, state), in arrival order
        self.held: dict[int, list[tuple[int, int, P]]] = {}

    def receive(self, k: int, ids: list[int], payloads: list[P], ready: list[int]) -> None:
        """States of step k heard from ids, each usable from its step in ready (deliver)."""
        for j, payload, at in zip(ids, payloads, ready):
            self.held.setdefault(j, []).append((at, k, payload))

    def passed_on(self, ready: int, j: int, at: int, payload: P) -> None:
        """j's state of step `at`, heard in another MAP's message usable from step `ready` (ear.Ear.hear_passed)."""
        self.held.setdefault(j, []).append((ready, at, payload))

    def newest(self, j: int) -> int:
        """The step of the newest state held from j (-1: none)."""
        return max((at for _, at, _ in self.held.get(j, ())), default=-1)

    def usable(self, k: int) -> list[tuple[int, int, P]]:
        """(neighbour id, age in steps, its latest state usable at step k), in ascending id; states too old to
        be used are forgotten."""
        ready_by, oldest = k, k - self.links.ttl
        out: list[tuple[int, int, P]] = []
        for j in sorted(self.held):
            states = self.held[j]
            ready = [s for s in states if s[0] <= ready_by]
            best = max(ready, key=lambda s: s[1]) if ready else None
            keep = ([best] if best is not None and best[1] >= oldest else []) + [s for s in states if s[0] > ready_by]
            if keep:
                self.held[j] = keep
            else:
                del self.held[j]
            if best is not None and best[1] >= oldest:
                out.append((j, k - best[1], best[2]))
        return out
