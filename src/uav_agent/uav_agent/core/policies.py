"""Allocations by name, and the step every MAP takes through the one its scenario chooses.

An allocation decides who serves which cluster and who relays where. Each implements `Allocation`;
`ALLOCATIONS` names them, and a scenario's `policies: allocation:` picks one (FlockParams.allocation).
Nothing else in uav-flock tests an allocation's name: a new one is a module and a line below
(docs/design.md, "Adding an allocation").
"""
from __future__ import annotations

from typing import Callable, Iterable, Protocol, Sequence

import numpy as np

from .allocations.algorithm2 import Algorithm2
from .allocations.demand import Demand
from .clusters import NO_GOAL, ClusterMap, merge_achieved
from .params import OPEN_CHOICES, SAFETY, FlockParams
from .params import check as check_values
from .state import NOBODY, UNKEPT, Memory, Near, Reference, Told


class Allocation(Protocol):
    """One MAP's discrete update and goal under an allocation, from its own sensing and its neighbours' words."""

    # Whether its MAPs pass on the neighbour states they hold under a lossy channel (rule 'hearsay',
    # ear.Ear): measured per allocation, since what holds one formation together can split another. One that
    # does not say passes nothing on (policies.hearsay).
    hearsay: bool

    def decide(self, mem: Memory, agent_id: int, n_users: int, r_g: float, q: np.ndarray, clusters: ClusterMap,
               fp: FlockParams, step: int = 0, near: Near = NOBODY) -> Memory:
        """Mode, goal and bridge after this step's gossip (Algorithm 2's place in Algorithm 1), at step k, with
        the neighbours where they are now (near)."""

    def reference(self, mem: Memory, agent_id: int, q: np.ndarray, nbr_q: np.ndarray, told: Sequence[Told],
                  clusters: ClusterMap, fp: FlockParams) -> Reference:
        """What eq. 9's goal term aims at."""

    def link(self, a: Told, b: Told, fp: FlockParams) -> int:
        """What the link between two MAPs that stated a and b is to the flocking terms: state.RELATED (all
        of eq. 10), APART (repulsion within d only), PASSING (repulsion within d/2 only) or INLINE (all of
        eq. 10 along the own MAP's edge only); fp says what they fly (envelope.limited)."""

    def needed(self, own: Memory, other: Told) -> int:
        """Who keeps the link between a MAP (its memory) and a neighbour that stated `other` against the nominal, if
        the network needs it kept (state.UNKEPT, SHARED or ALONE): the safety filter's rule 'links' protects such links
        only (control.control_input). One that does not say keeps none (policies.needed)."""


ALLOCATIONS: dict[str, Allocation] = {
    'demand': Demand(),
    'algorithm2': Algorithm2(),
}
DEFAULT = FlockParams().allocation  # what a scenario without `policies: allocation:` runs
# Every choice where the paper is ambiguous or leaves the method open, with its allowed values (docs/choices.md).
POLICY_VALUES: dict[str, tuple[str, ...]] = {'allocation': tuple(ALLOCATIONS), **OPEN_CHOICES, 'safety': SAFETY}


def check(p: FlockParams, where: Callable[[str], str] = str) -> None:
    """params.check with every policy's allowed values: ValueError naming the parameter as `where(name)` does."""
    check_values(p, where, POLICY_VALUES)


def decide(mem: Memory, agent_id: int, n_users: int, cluster_coverage: np.ndarray, q: np.ndarray,
           neighbour_achieved: Iterable[int], clusters: ClusterMap, fp: FlockParams, step: int = 0,
           near: Near = NOBODY) -> Memory:
    """One MAP's discrete update at step k: gossip of the achieved goals, then its allocation (which hears
    what else its neighbours told: near.told)."""
    achieved = merge_achieved(mem.achieved, neighbour_achieved)
    if achieved != mem.achieved:
        mem = mem._replace(achieved=achieved)
    r_g = float(cluster_coverage[mem.goal]) if mem.goal != NO_GOAL else 0.0
    return ALLOCATIONS[fp.allocation].decide(mem, agent_id, n_users, r_g, q, clusters, fp, step, near)


def reference(mem: Memory, agent_id: int, q: np.ndarray, nbr_q: np.ndarray, told: Sequence[Told],
              clusters: ClusterMap, fp: FlockParams) -> Reference:
    return ALLOCATIONS[fp.allocation].reference(mem, agent_id, q, nbr_q, told, clusters, fp)


def links(mem: Memory, heard: Sequence[Told], fp: FlockParams) -> list[int]:
    """For each neighbour heard, what its link to this MAP (as decided this step) is to the flocking terms."""
    own, allocation = Told.of(mem), ALLOCATIONS[fp.allocation]
    return [allocation.link(own, t, fp) for t in heard]


def needed(mem: Memory, heard: Sequence[Told], fp: FlockParams, free: bool = False) -> list[int]:
    """For each neighbour heard, who keeps its link to this MAP, if the network needs it kept (Allocation.needed:
    state.UNKEPT, SHARED or ALONE); none without the safety filter, which alone keeps them, nor while rule
    'release' sets the MAP free of them."""
    allocation = ALLOCATIONS[fp.allocation]
    if fp.safety != 'filter' or not hasattr(allocation, 'needed') or free:
        return [UNKEPT] * len(heard)
    return [allocation.needed(mem, t) for t in heard]


def hearsay(fp: FlockParams) -> bool:
    """Whether the scenario's allocation passes on what its MAPs hear (Allocation.hearsay; False if it does not say)."""
    return bool(getattr(ALLOCATIONS[fp.allocation], 'hearsay', False))
