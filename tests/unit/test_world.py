"""World physics and metrics against brute force and closed forms."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from world_sim.core import physics
from world_sim.core.scenario import load

RHO, ETA, R = 1.0, 3.5, 24.0


def users_at(xy: np.ndarray) -> physics.Users:
    return physics.Users(np.column_stack([xy, np.zeros(len(xy))]), np.zeros(len(xy), np.intp), xy.mean(axis=0, keepdims=True))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 40), st.integers(1, 300), st.sampled_from(['3d', 'horizontal']))
def test_association_equals_brute_force_of_eq2(seed: int, n_maps: int, n_users: int, mode: str) -> None:
    rng = np.random.default_rng(seed)
    users = users_at(rng.uniform(-60, 60, (n_users, 2)))
    q = np.column_stack([rng.uniform(-60, 60, (n_maps, 2)), np.full(n_maps, 20.0)])
    got = physics.associate(users, q, R, mode)
    a, b = (users.xyz[:, :2], q[:, :2]) if mode == 'horizontal' else (users.xyz, q)
    dist = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)
    signal = np.where(dist <= R, RHO * dist ** -ETA, -np.inf)
    expect = np.where(np.isfinite(signal.max(axis=1)), signal.argmax(axis=1), physics.UNSERVED)
    assert np.array_equal(got, expect)


def test_counts_and_coverage() -> None:
    users = physics.Users(np.zeros((6, 3)), np.array([0, 0, 0, 1, 1, 1]), np.zeros((2, 2)))
    assoc = np.array([0, 0, physics.UNSERVED, 2, physics.UNSERVED, physics.UNSERVED])
    assert physics.user_counts(assoc, 3).tolist() == [2, 0, 1]
    assert physics.cluster_coverage(users, assoc).tolist() == pytest.approx([2 / 3, 1 / 3])
    assert physics.coverage_ratio(assoc) == pytest.approx(0.5)


def _pairs(edges: list[tuple[int, int]]) -> np.ndarray:
    both = [(i, j) for i, j in edges] + [(j, i) for i, j in edges]
    return np.array(sorted(both), dtype=np.intp).reshape(-1, 2)


@pytest.mark.parametrize('n', [2, 3, 5, 10, physics.SPARSE_FROM + 100])
def test_fiedler_of_a_path(n: int) -> None:
    assert physics.fiedler(_pairs([(i, i + 1) for i in range(n - 1)]), n) == pytest.approx(2 * (1 - np.cos(np.pi / n)))


@pytest.mark.parametrize('n', [2, 4, 7, physics.SPARSE_FROM + 10])
def test_fiedler_of_a_complete_graph(n: int) -> None:
    assert physics.fiedler(_pairs([(i, j) for i in range(n) for j in range(i + 1, n)]), n) == pytest.approx(n)


def test_fiedler_of_a_large_formation_is_the_dense_value() -> None:
    """Above SPARSE_FROM MAPs lambda2 comes from the sparse Laplacian: the same value as the dense solver's to
    1e-9 relative, and the same bits on every call."""
    rng = np.random.default_rng(3)
    n = physics.SPARSE_FROM + 200
    q = np.column_stack([rng.uniform(0, 300, n), rng.uniform(0, 300, n), np.zeros(n)])
    pairs = physics.neighbour_pairs(q, 24.0)
    assert physics.components(pairs, n) == 1, 'a connected draw'
    dense = np.linalg.eigvalsh(physics.laplacian(pairs, n))[1]
    assert physics.fiedler(pairs, n) == pytest.approx(dense, rel=1e-9)
    assert physics.fiedler(pairs, n) == physics.fiedler(pairs, n)


def test_fiedler_of_a_packed_square_of_many_maps_is_the_dense_value() -> None:
    """Above DENSE_UNTIL MAPs a packed release square (mean degree in the hundreds, where below it the dense
    solver is quicker) also goes to the sparse solver: `sim --maps 5000` sat minutes at its first step on it."""
    rng = np.random.default_rng(5)
    n = physics.DENSE_UNTIL + 100
    q = np.column_stack([rng.uniform(0, 150, n), rng.uniform(0, 150, n), np.zeros(n)])
    pairs = physics.neighbour_pairs(q, 24.0)
    assert len(pairs) > physics.SPARSE_DEGREE * n, 'packed: denser than the sparse rule alone takes'
    dense = np.linalg.eigvalsh(physics.laplacian(pairs, n))[1]
    assert physics.fiedler(pairs, n) == pytest.approx(dense, rel=1e-9)


def test_fiedler_of_a_disconnected_graph_is_zero() -> None:
    pairs = _pairs([(0, 1), (2, 3)])
    assert physics.components(pairs, 4) == 2
    assert physics.fiedler(pairs, 4) == 0.0
    assert np.linalg.eigvalsh(physics.laplacian(pairs, 4))[1] == pytest.approx(0.0, abs=1e-12)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(0, 60))
def test_neighbour_pairs_equal_brute_force(seed: int, n: int) -> None:
    q = np.random.default_rng(seed).uniform(-50, 50, (n, 3))
    d = np.linalg.norm(q[:, None] - q[None], axis=-1)
    expect = [(i, j) for i in range(n) for j in range(n) if i != j and d[i, j] <= R]
    assert physics.neighbour_pairs(q, R).tolist() == [list(e) for e in expect]


def test_integration_is_exact_for_constant_input() -> None:
    q, p, u = np.array([[1.0, 2.0, 20.0]]), np.array([[0.5, -1.0, 0.0]]), np.array([[0.2, 0.1, 0.0]])
    qk, pk = q, p
    for _ in range(50):
        qk, pk = physics.integrate(qk, pk, u, 0.1)
    t = 5.0
    assert np.allclose(qk, q + p * t + 0.5 * u * t * t) and np.allclose(pk, p + u * t)


def test_failure_ids_are_reproducible_and_sized(paper_scenario_path: str) -> None:
    s = load(paper_scenario_path).with_overrides(maps=80, fail_fraction=0.3, fail_at=18.0)
    ids = np.arange(80)
    a = physics.failure_ids(s, ids, physics.streams(s.seed)['failure'])
    b = physics.failure_ids(s, ids, physics.streams(s.seed)['failure'])
    assert len(a) == 24 and np.array_equal(a, b) and len(set(a.tolist())) == 24


def test_users_follow_the_scenario(paper_scenario_path: str) -> None:
    s = load(paper_scenario_path)
    users = physics.make_users(s, physics.streams(s.seed)['users'])
    assert users.cluster_sizes.tolist() == [c.size for c in s.clusters]
    for k, c in enumerate(s.clusters):
        assert np.linalg.norm(users.centroids[k] - c.center) < 3 * c.spread / np.sqrt(c.size) * 3


def test_one_map_serving_its_cluster_is_a_network_that_succeeds() -> None:
    """A single MAP over a small cluster covers it; its lambda2 is 0, but one MAP is one network: the run succeeds."""
    import yaml
    from uav_flock_tools.batch import BatchSimulator
    from world_sim.core import outcome
    from world_sim.core.scenario import parse
    from world_sim.shipped import resolve
    doc = yaml.safe_load(resolve('paper').read_text())
    doc.update(name='one', maps=1, duration=20.0)
    doc['release']['half_width'] = 5.0
    doc['users']['clusters'] = [{'center': [-130.0, 50.0], 'spread': 2.0, 'size': 5}]
    m = BatchSimulator(parse(doc)).run().metrics
    assert m[-1, 2] == 1.0 and m[-1, 3] == 0.0, 'covered, with the lambda2 of a single MAP'
    assert outcome.time_to_success(m) < 20.0
    assert outcome.joined(m).all()


def test_a_stalled_step_watches_the_live_neighbours_of_the_maps_it_waits_for() -> None:
    """MAP 0 waits for its neighbour 2's state; 2's command is in, so the world does not wait for 2 itself. If
    2's node was killed after it sent that command, only watching 2 ends the stall (watch.watched)."""
    from world_sim.core.model import Sensed
    from world_sim.watch import watched
    ids = np.array([0, 1, 2, 3, 5])
    # rows 0-2 (ids 0 and 2), 0-3 (ids 0 and 3), 1-4 (ids 1 and 5), both ways, sorted
    edges = [(0, 2), (0, 3), (1, 4)]
    pairs = np.array(sorted(e for a, b in edges for e in ((a, b), (b, a))))
    n = len(ids)
    s = Sensed(7, ids, np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n), np.zeros(1), pairs, 1.0)
    alive = np.ones(6, dtype=bool)
    assert watched(s, [0], alive) == [0, 2, 3]
    alive[3] = False  # already dropped: nothing to watch
    assert watched(s, [0], alive) == [0, 2]
    assert watched(s, [0, 5], alive) == [0, 1, 2, 5]
    assert watched(s, [], alive) == []
