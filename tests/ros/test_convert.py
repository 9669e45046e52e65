"""uav_flock_ros.convert: every message type's values read back equal from an rclpy message, from its
wire bytes and from what rosbags deserializes out of a bag."""
from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from std_msgs.msg import Header
from uav_flock_ros import convert
from uav_flock_tools import bag

FINITE = st.floats(-1e6, 1e6, allow_nan=False)
HDR = Header(frame_id='world')
U32 = st.integers(0, 2**32 - 1)
VEC = arrays(np.float64, 3, elements=FINITE)
STORE = bag.typestore()


def through_a_bag(raw: bytes, name: str) -> Any:
    """The message as bag reading takes it: written into a real MCAP bag, read back with rosbags."""
    with tempfile.TemporaryDirectory() as tmp:
        with Writer(Path(tmp) / 'bag', version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            writer.write(writer.add_connection('/t', name, typestore=STORE), 0, raw)
        with AnyReader([Path(tmp) / 'bag'], default_typestore=STORE) as reader:
            [(conn, _, got)] = list(reader.messages())
            return bag.deserialize(reader, got, conn.msgtype)


def rows(n: Any, width: int) -> Any:
    return arrays(np.float64, st.tuples(n, st.just(width)), elements=FINITE)


def ids(n: int = 12) -> Any:
    return st.lists(st.integers(0, 500), max_size=n, unique=True).map(lambda v: np.array(sorted(v), dtype=np.intp))


STATE = (U32, st.integers(0, 2**63), VEC, VEC, U32, st.integers(0, 2), st.integers(-1, 99),
         st.one_of(st.none(), st.tuples(st.integers(0, 99), st.integers(0, 99))),
         st.lists(st.integers(0, 99), unique=True).map(lambda v: tuple(sorted(v))),
         st.one_of(st.none(), st.builds(
             convert.RoleGossipData, st.booleans(),
             st.dictionaries(st.integers(0, 4095), st.integers(0, 2**63), max_size=12).map(lambda d: tuple(sorted(d.items()))),
             st.lists(st.tuples(st.floats(0, 1), st.floats(0, 1)), max_size=6).map(tuple),
             st.dictionaries(st.integers(0, 4095), st.integers(0, 2**32 - 1), max_size=12).map(
                 lambda d: tuple(sorted(d.items()))))))
VALUES = {
    convert.AgentStateData: st.builds(convert.AgentStateData, *STATE,
                                      st.lists(st.builds(convert.PassedData, *STATE), max_size=8).map(tuple)),
    convert.CommandData: st.builds(convert.CommandData, U32, st.integers(0, 2**63), VEC, st.integers(0, 2),
                                   st.integers(-1, 99), st.integers(0, 3)),
    convert.SensingData: st.tuples(ids(), ids(8)).flatmap(lambda nt: st.builds(
        convert.SensingData, U32, st.integers(0, 2**63), VEC, VEC, U32, st.floats(0, 1), st.just(nt[0]),
        arrays(np.float64, len(nt[0]), elements=st.floats(0, 1e4)), U32, st.just(nt[1]),
        rows(st.just(len(nt[1])), 3), rows(st.just(len(nt[1])), 3))),
    convert.UsersData: st.integers(0, 30).flatmap(lambda m: st.builds(
        convert.UsersData, st.integers(0, 2**63), rows(st.just(m), 3),
        arrays(np.intp, m, elements=st.integers(-1, 20)))),
    convert.ClustersData: st.integers(1, 8).flatmap(lambda k: st.builds(
        convert.ClustersData, U32, rows(st.just(k), 2), arrays(np.intp, k, elements=st.integers(0, 1000)),
        st.one_of(st.none(), arrays(np.float64, k, elements=st.floats(0, 100))),
        arrays(np.bool_, k), rows(st.just(k), 2))),
    convert.AssociationData: ids().flatmap(lambda n: st.builds(
        convert.AssociationData, st.integers(0, 2**63), st.just(n), arrays(np.intp, len(n), elements=U32),
        arrays(np.float64, st.integers(0, 8), elements=st.floats(0, 1)), st.floats(0, 1))),
    convert.MetricsData: st.builds(convert.MetricsData, st.integers(0, 2**63), FINITE, st.floats(0, 1), FINITE,
                                   U32, U32, U32, U32, U32,
                                   st.one_of(st.none(), st.tuples(FINITE, U32, FINITE, U32, st.floats(0, 1), U32)),
                                   st.one_of(st.none(), st.tuples(FINITE, FINITE, FINITE, U32, U32))),
    convert.FailureData: st.builds(convert.FailureData, st.integers(0, 2**63), ids().map(lambda a: tuple(a.tolist())),
                                   st.sampled_from(['scheduled', 'killed'])),
}


def same(a: NamedTuple, b: NamedTuple) -> bool:
    return type(a) is type(b) and all(
        (x is None and y is None) or (hasattr(x, '_fields') and same(x, y))
        or (isinstance(x, tuple) and any(hasattr(e, '_fields') for e in x)
            and len(x) == len(y) and all(same(e, f) for e, f in zip(x, y)))
        or (x is not None and y is not None and equal(x, y)) for x, y in zip(a, b))


def equal(x: object, y: object) -> bool:
    """Values equal, NaN to NaN included: the world reports no least distance (NaN) under two MAPs."""
    try:
        return bool(np.array_equal(x, y, equal_nan=True))
    except TypeError:  # strings and other values NaN means nothing to
        return bool(np.array_equal(x, y))


def expected(v: NamedTuple) -> NamedTuple:
    """What a reader gets back: /clusters leaves out `active` when all exist and velocities when none move."""
    if isinstance(v, convert.ClustersData):
        return v._replace(active=v.active if not v.active.all() else np.ones(len(v.xy), bool),
                          velocities=v.velocities if np.any(v.velocities) else np.zeros_like(v.velocities))
    return v


@pytest.mark.parametrize('kind', list(VALUES), ids=lambda k: k.__name__)
def test_every_message_round_trips_through_the_wire_and_a_bag(kind: type) -> None:
    @settings(max_examples=25, deadline=None)
    @given(VALUES[kind])
    def check(values: NamedTuple) -> None:
        msg = values.to_msg(HDR)
        raw = serialize_message(msg)
        want = expected(values)
        assert same(kind.from_msg(msg), want)
        assert same(kind.from_msg(deserialize_message(raw, type(msg))), want), 'from the wire'
        name = type(msg).__module__.split('.')[0] + '/msg/' + type(msg).__name__
        assert same(kind.from_msg(through_a_bag(raw, name)), want), 'as bag reading takes it from a bag'
    check()


def test_clusters_without_radii_read_back_as_none() -> None:
    """An older recording has no radii, and the reader says so rather than inventing them."""
    msg = convert.ClustersData(0, np.zeros((2, 2)), np.ones(2), np.ones(2), np.ones(2, bool), np.zeros((2, 2))).to_msg(HDR)
    msg.radii = []
    assert convert.ClustersData.from_msg(msg).radii is None


def test_stamped_id_step_reads_the_wire_bytes_of_states_and_commands() -> None:
    for frame in ('', 'w', 'world', 'x' * 13):
        for values in (convert.CommandData(77, 123456789012, np.zeros(3), 1, 2),
                       convert.AgentStateData(77, 123456789012, np.zeros(3), np.zeros(3), 0, 0, -1, None, ())):
            raw = serialize_message(values.to_msg(Header(frame_id=frame)))
            assert convert.stamped_id_step(raw) == (77, 123456789012)
