"""What the demand allocation keeps of its own from step to step, and what it adds to a MAP's state message.

A MAP's common memory (state.Memory) holds its mode, goal, achieved goals and bridge; the demand
allocation keeps the rest in `Own` (Memory.own) and tells its neighbours `Gossip` (Told.block, the
`roles` block of /map_<id>/state). Its rules read and write one record, `Mine`: the two joined.
"""
from __future__ import annotations

from typing import NamedTuple, Optional

from ...state import Memory, Told
from .keys import Span


class Gossip(NamedTuple):
    """What a MAP under the demand allocation tells its neighbours besides its role, O(roles) numbers: whether it
    is on its way to a new role, what it gossips of the roles (vacancy.py), and whether it has reached its role's
    place (settled: the links the safety filter keeps join settled MAPs only, Demand.needed)."""

    transit: bool = False
    seen: tuple[tuple[int, int], ...] = ()   # (role code, last step a member was heard of)
    lost: tuple[Span, ...] = ()              # spans of keys known lost
    short: tuple[tuple[int, int], ...] = ()  # (role code, MAPs it was found short of)
    ends: tuple[float, ...] = ()             # a relay's chain ends: hops and place below, hops and place above (chain.Ends)
    settled: bool = False                    # it has reached its role's place once (Own.settled)


SILENT = Gossip()  # what a neighbour that said nothing of its own (step 0, or another allocation) counts as


def gossip_of(told: Told) -> Gossip:
    return told.block if told.block is not None else SILENT


class Own(NamedTuple):
    """The demand allocation's memory: whether it has reached its role's place once, and whether it is on its
    way to a new role since (transit: a role change after settling, flown along the tree); a relay whose edge
    left the tree for one with a cluster in common swings about that cluster (swing: the pivot and its place
    along the gap). What it gossips of the roles (vacancy.py): the last step a member of each role was heard of,
    as sorted (role code, step) pairs; the spans of keys known lost; the roles found short, as (role code,
    MAPs); and the step it last reached its role's place. A relay counts the steps it has found its chain taut
    (taut). A relay released from a chain that stood out of the tree to one of its clusters flies straight
    there, along its own chain (straight; layout.standing), not along the tree. Under a lossy channel a MAP
    keeps the last step its links were whole (whole: a relay heard its chain on both sides, a server a relay of
    its cluster) and, while they have been broken no longer than the channel's losses last, the place it holds
    (hold: a relay's place along its edge, a server's offset from its cluster's centre; demand.hushed,
    demand.anchored). A settled relay on a lagged vehicle keeps and tells its chain's ends as it last heard them
    (ends: chain.Ends as four numbers, or none; rule 'ends'). On a lagged vehicle under the paper's channel it keeps
    the relays it heard at its last step well within r, each as (x, y, role code), to see which of them failed
    (around: vacancy.vanished); it never tells them. A relay let go from a standing chain on a lagged vehicle
    keeps the cluster its key named then and the nearer one it joined instead (rejoin: demand.rejoined); never
    told either."""

    settled: bool = False
    transit: bool = False
    swing: Optional[tuple[int, float]] = None
    seen: tuple[tuple[int, int], ...] = ()
    lost: tuple[Span, ...] = ()
    short: tuple[tuple[int, int], ...] = ()
    since: int = -1
    taut: int = 0
    straight: bool = False
    whole: int = -1
    hold: Optional[tuple[float, ...]] = None
    ends: tuple[float, ...] = ()
    around: tuple[tuple[float, float, int], ...] = ()
    rejoin: Optional[tuple[int, int]] = None

    def said(self) -> Gossip:
        """What the MAP's state message carries of it (Told.block)."""
        return Gossip(self.transit, self.seen, self.lost, self.short, self.ends, self.settled)


COMMON = ('mode', 'goal', 'achieved', 'bridge')  # Memory's fields every allocation has
# The fields of Mine: the common ones, then the allocation's own, each with its default.
_Joined = NamedTuple('_Joined', [*((f, Memory.__annotations__[f]) for f in COMMON), *Own.__annotations__.items()])
_Joined.__new__.__defaults__ = (*(Memory._field_defaults[f] for f in COMMON), *Own._field_defaults.values())


class Mine(_Joined):
    """A MAP's memory as the demand allocation's rules read and write it: the common fields, then its own
    (`Mine._fields`: mode, goal, achieved, bridge, then Own's)."""

    __slots__ = ()

    @classmethod
    def of(cls, mem: Memory) -> 'Mine':
        own = mem.own if isinstance(mem.own, Own) else Own()
        return cls(mem.mode, mem.goal, mem.achieved, mem.bridge, *own)

    def memory(self) -> Memory:
        return Memory(self.mode, self.goal, self.achieved, self.bridge, Own(*self[len(COMMON):]))

    def told(self) -> Told:
        """What its state message says of its role."""
        return Told(self.mode, self.goal, self.bridge, Own(*self[len(COMMON):]).said())
