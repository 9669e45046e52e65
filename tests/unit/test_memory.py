"""The demand allocation's memory and gossip (core/allocations/demand/memory.py): the common memory keeps
five fields, the allocation's own round-trips through it, and a MAP tells its neighbours what it holds."""
from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from uav_agent.core.allocations.demand.memory import SILENT, Gossip, Mine, Own, gossip_of
from uav_agent.core.state import M1, Memory, Told

PAIRS = st.lists(st.tuples(st.integers(0, 4095), st.integers(0, 10**6)), max_size=5).map(lambda v: tuple(sorted(v)))
MINE = st.builds(  # each field drawn as its type says (Own's annotations)
    Mine, mode=st.integers(0, 2), goal=st.integers(-1, 9), achieved=st.integers(0, 511),
    bridge=st.one_of(st.none(), st.tuples(st.integers(0, 4), st.integers(5, 9))), settled=st.booleans(),
    transit=st.booleans(), swing=st.one_of(st.none(), st.tuples(st.integers(0, 9), st.floats(0, 1))), seen=PAIRS,
    lost=st.lists(st.tuples(st.floats(0, 0.5), st.floats(0.5, 1)), max_size=3).map(tuple), short=PAIRS,
    since=st.integers(-1, 999), taut=st.integers(0, 999), straight=st.booleans(), whole=st.integers(-1, 999),
    hold=st.one_of(st.none(), st.lists(st.floats(-50, 50), min_size=1, max_size=2).map(tuple)),
    ends=st.one_of(st.just(()), st.lists(st.floats(0, 99), min_size=4, max_size=4).map(tuple)),
    around=st.lists(st.tuples(st.floats(-99, 99), st.floats(-99, 99), st.integers(0, 9)), max_size=3).map(tuple),
    rejoin=st.one_of(st.none(), st.tuples(st.integers(0, 9), st.integers(0, 9))))


def test_the_common_memory_holds_five_fields() -> None:
    assert len(Memory._fields) <= 5


@given(MINE)
def test_the_allocations_record_round_trips_through_the_common_memory(mine: Mine) -> None:
    mem = mine.memory()
    assert isinstance(mem.own, Own) and Mine.of(mem) == mine
    assert Told.of(mem) == mine.told(), 'what the MAP says is what its rules hold'
    assert Told.of(mem).block == Gossip(mine.transit, mine.seen, mine.lost, mine.short, mine.ends, mine.settled)


def test_a_neighbour_that_said_nothing_of_its_own_counts_as_silent() -> None:
    assert Mine.of(Memory()) == Mine(), 'a MAP starts with the allocation\'s defaults'
    assert Told.of(Memory()).block is None and gossip_of(Told(M1, 0, (0, 1))) == SILENT
