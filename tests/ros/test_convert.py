"""uav_flock_ros.convert: every message it builds reads back to the arrays it was built from."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from std_msgs.msg import Header
from uav_flock_msgs.msg import AgentState
from uav_flock_ros import convert

FINITE = st.floats(-1e6, 1e6, allow_nan=False)
HDR = Header(frame_id='world')


@settings(max_examples=30, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(0, 20), st.just(3)), elements=FINITE), st.integers(1, 5))
def test_users_round_trip(xyz: np.ndarray, k: int) -> None:
    cluster = np.arange(len(xyz)) % (k + 1) - 1  # -1: an MSD in no cluster
    msg = convert.users(HDR, 42, xyz, cluster)
    back_xyz, back_cluster = convert.users_arrays(msg)
    assert msg.step == 42 and np.array_equal(back_xyz, xyz) and np.array_equal(back_cluster, cluster)


@settings(max_examples=30, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 8), st.just(2)), elements=FINITE))
def test_clusters_round_trip_with_and_without_radii(xy: np.ndarray) -> None:
    sizes = np.arange(1, len(xy) + 1)
    radii = np.linspace(10.0, 40.0, len(xy))
    back = convert.clusters_arrays(convert.clusters(HDR, 0, xy, sizes, radii))
    assert np.array_equal(back.xy, xy) and np.array_equal(back.sizes, sizes) and np.array_equal(back.radii, radii)
    assert back.version == 0 and back.active.all() and not back.velocities.any()
    msg = convert.clusters(HDR, 0, xy, sizes, radii)
    msg.radii = []  # an older recording: no radii, and the reader says so rather than inventing them
    assert convert.clusters_arrays(msg).radii is None


@settings(max_examples=30, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 8), st.just(2)), elements=FINITE), st.integers(0, 1000))
def test_clusters_of_a_survey_round_trip_with_ended_ids_and_velocities(xy: np.ndarray, version: int) -> None:
    sizes = np.arange(len(xy)) * 10
    active = sizes > 0
    vel = xy[::-1] / 100.0
    back = convert.clusters_arrays(convert.clusters(HDR, version, xy, sizes, np.ones(len(xy)), active, vel))
    assert back.version == version and np.array_equal(back.active, active)
    assert np.array_equal(back.velocities, vel if np.any(vel) else np.zeros_like(vel))


def test_association_and_sensing_carry_what_they_were_built_from() -> None:
    a = convert.association(HDR, 7, np.array([0, 2, 5]), np.array([3, 0, 9]), np.array([0.5, 1.0]), 0.75)
    assert (a.step, list(a.map_ids), list(a.user_counts), list(a.cluster_coverage), a.coverage_ratio) == \
        (7, [0, 2, 5], [3, 0, 9], [0.5, 1.0], 0.75)
    q, p = np.array([1.0, 2.0, 20.0]), np.array([0.5, -0.5, 0.0])
    nq = np.array([[4.0, 6.0, 20.0], [1.0, 2.0, 30.0]])
    s = convert.sensing(HDR, 3, 7, q, p, 12, 0.9, np.array([1, 4]), nq, clusters_version=5)
    assert (s.id, s.step, s.user_count, s.goal_coverage, s.clusters_version) == (3, 7, 12, 0.9, 5)
    assert np.array_equal(convert.xyz(s.position), q) and np.array_equal(convert.xyz(s.velocity), p)
    assert list(s.neighbors.ids) == [1, 4] and np.allclose(s.neighbors.distances, [5.0, 10.0])


def test_a_states_role_reads_back() -> None:
    assert convert.role(AgentState(mode=1, goal=2, bridge=[2, 5])) == (1, 2, (2, 5))
    assert convert.role(AgentState(mode=2, goal=0, bridge=[])) == (2, 0, None)
