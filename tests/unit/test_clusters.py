"""Cluster geometry every MAP shares (core/clusters.py): achieved-goal masks, the tree, hops along it, gaps."""
from __future__ import annotations

import itertools

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from uav_agent.core.clusters import NO_GOAL, ClusterMap, ids_of, mask_of, merge_achieved, mst_edges

POINTS = st.lists(st.tuples(st.integers(-500, 500), st.integers(-500, 500)), min_size=2, max_size=7, unique=True)


@given(st.sets(st.integers(0, 62)))
def test_a_mask_holds_exactly_its_ids_and_gossip_is_their_union(ids: set[int]) -> None:
    assert ids_of(mask_of(ids)) == sorted(ids)
    half = sorted(ids)[::2]
    assert merge_achieved(mask_of(half), [mask_of(ids)]) == mask_of(ids)


@settings(max_examples=50, deadline=None)
@given(POINTS)
def test_the_tree_is_no_longer_than_any_other_spanning_tree(points: list[tuple[int, int]]) -> None:
    """Brute force over every set of n - 1 edges that connects the points (n <= 7)."""
    xy = np.array(points, dtype=float)
    n = len(xy)
    tree = mst_edges(xy)
    length = sum(np.linalg.norm(xy[a] - xy[b]) for a, b in tree)
    assert len(tree) == n - 1 and all(a < b for a, b in tree)
    for edges in itertools.islice(itertools.combinations(itertools.combinations(range(n), 2), n - 1), 3000):
        reach = {0}
        for _ in range(n):
            reach |= {b for a, b in edges if a in reach} | {a for a, b in edges if b in reach}
        if len(reach) == n:
            assert length <= sum(np.linalg.norm(xy[a] - xy[b]) for a, b in edges) + 1e-9


def test_a_hop_follows_the_tree_and_an_ended_cluster_is_nobodys_nearest() -> None:
    row = ClusterMap(np.array([[0.0, 0.0], [100.0, 0.0], [200.0, 0.0], [100.0, 120.0]]), 20.0, np.full(4, 25.0))
    assert row.mst(row.live) == ((0, 1), (1, 2), (1, 3))
    assert row.tree_hop(0, 2) == 1 and row.tree_hop(1, 2) == 2 and row.tree_hop(3, 0) == 1
    ended = ClusterMap(row.xy, 20.0, row.radii, active=np.array([True, False, True, True]))
    assert ended.nearest(np.array([100.0, 0.0, 20.0]), 0) != 1
    assert ended.nearest(np.zeros(3), ended.live) == NO_GOAL, 'every existing cluster excluded'


def test_the_gap_of_an_edge_runs_between_its_clusters_outermost_servers() -> None:
    pair = ClusterMap(np.array([[0.0, 0.0], [100.0, 0.0]]), 20.0, np.array([30.0, 20.0]))
    assert pair.gap((0, 1), 10.0) == (20.0, 90.0), 'half a lattice spacing inside each disc'
    touching = ClusterMap(pair.xy, 20.0, np.array([60.0, 60.0]))
    assert touching.gap((0, 1), 10.0) == (0.0, 100.0), 'discs that meet: the whole edge'
