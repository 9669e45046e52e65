"""The demand allocation's roles (core/allocations/demand/layout.py): shares by demand, keys carried across surveys, kept shares, standing chains."""
from __future__ import annotations

import collections
from dataclasses import replace
import math
from typing import Any, Callable

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uav_agent.core.ablation import switched_off
from uav_agent.core.allocations.demand import layout
from uav_agent.core.allocations.demand.allocation import demand_switch, en_route
from uav_agent.core.allocations.demand.memory import Mine
from uav_agent.core.clusters import NO_GOAL, ClusterMap, key_of
from uav_agent.core.params import FlockParams
from uav_agent.core.state import M1
from helpers.roles import role_ids
from world_sim.core import vehicle


def test_when_a_cluster_leaves_only_its_own_maps_change_role() -> None:
    """Laid out end to end afresh, the first cluster leaving would shift every share and move most MAPs;
    carried across the survey, the keys of its servers and its edge's relays go to the roles left, and no
    other MAP changes role."""
    fp, n = FlockParams(), 120
    xy, radii = np.array([[0.0, 0.0], [150.0, 0.0], [300.0, 0.0], [450.0, 0.0]]), np.full(4, 30.0)
    before = ClusterMap(xy, fp.height, radii)
    gone = np.array([False, True, True, True])
    carried = role_ids(ClusterMap(xy, fp.height, radii, active=gone, previous=before), n, fp)
    afresh = role_ids(ClusterMap(xy, fp.height, radii, active=gone), n, fp)
    old = role_ids(before, n, fp)
    own = {i for i in range(n) if old[i] in (0, (0, 1))}
    assert {i for i in range(n) if carried[i] != old[i]} == own, 'exactly the MAPs of the roles that ended'
    others = sum(afresh[i] != old[i] for i in range(n) if i not in own)
    assert others >= 10, f'end to end, MAPs of the roles that stayed would have moved too (here {others})'
    assert 0 not in carried and (0, 1) not in carried


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 6), st.integers(0, 2**32 - 1), st.sampled_from(['leave', 'grow', 'shrink', 'move']))
def test_keys_carried_across_a_survey_move_few_maps_and_keep_every_share(k: int, seed: int, change: str) -> None:
    """Whatever the survey changes, the carried keys tile [0, 1), each role holds its new share (to a
    fragment), and the MAPs that change role are about those the change of shares forces to move."""
    fp, n = FlockParams(), 150
    rng = np.random.default_rng(seed)
    xy, radii = rng.uniform(0, 400, size=(k, 2)), rng.uniform(20, 45, size=k)
    before = ClusterMap(xy, fp.height, radii)
    xy, radii, active, c = xy.copy(), radii.copy(), np.ones(k, dtype=bool), int(rng.integers(k))
    if change == 'leave':
        active[c] = False
    elif change == 'move':
        xy[c] += rng.uniform(-60, 60, size=2)  # may change the tree
    else:
        radii[c] *= 1.4 if change == 'grow' else 0.7
    after = ClusterMap(xy, fp.height, radii, active=active, previous=before)
    old, new = layout.roles(before, fp.d), layout.roles(after, fp.d)
    pieces = new.pieces
    assert pieces[0][0] == 0.0 and abs(pieces[-1][1] - 1.0) < 1e-9
    assert all(abs(a[1] - b[0]) < 1e-12 for a, b in zip(pieces, pieces[1:])), 'the pieces tile [0, 1)'
    ids = [*range(after.count), *new.edges]
    for role, share in zip(ids, new.share):
        held = sum(hi - lo for lo, hi, r in pieces if r == role)
        assert abs(held - share) < 0.01, (role, held, share)
    old_ids = [*range(before.count), *old.edges]
    old_share = dict(zip(old_ids, old.share))
    forced = sum(max(old_share.get(r, 0.0) - s, 0.0) for r, s in zip(ids, new.share)) + \
        sum(v for r, v in old_share.items() if r not in ids)
    moved = sum(a != b for a, b in zip(role_ids(before, n, fp), role_ids(after, n, fp)))
    assert moved <= n * forced + 2 * len(ids), (moved, n * forced)


def test_a_cluster_that_shrinks_keeps_its_servers_and_calls_nobody_back_when_it_grows_again(monkeypatch: Any) -> None:
    """A drifting cluster's surveyed extent shrinks and grows back. Shares in proportion to demand sent its
    servers across the field to the other clusters and called them back; kept shares let it hold them while
    every other cluster holds its floor (layout.kept): only the edges, which take their share at once, grow."""
    fp, n = FlockParams(), 150
    xy = np.array([[0.0, 0.0], [150.0, 0.0], [300.0, 0.0], [300.0, 150.0]])
    radii = np.full(4, 40.0)
    small = radii.copy()
    small[0] = 32.0

    def survey_by_survey() -> tuple[list[Any], list[Any], list[Any]]:
        first = ClusterMap(xy, fp.height, radii)
        out = [role_ids(first, n, fp)]
        shrunk = ClusterMap(xy, fp.height, small, previous=first)
        out.append(role_ids(shrunk, n, fp))  # laid out before the next survey drops the one it carries from
        out.append(role_ids(ClusterMap(xy, fp.height, radii, previous=shrunk), n, fp))
        return out[0], out[1], out[2]

    a, b, c = survey_by_survey()
    left = [(a[i], b[i]) for i in range(n) if a[i] != b[i]]
    assert all(isinstance(new, tuple) for _, new in left), f'servers go to edges only, not to clusters: {left}'
    assert b == c, 'growing back, the cluster calls nobody back'
    monkeypatch.setattr(layout, 'SLACK', 0.0)
    a0, b0, c0 = survey_by_survey()
    assert any(isinstance(new, int) for old, new in zip(a0, b0) if old != new), \
        'in proportion to demand, servers would go to the other clusters'
    assert sum(x != y for x, y in zip(b0, c0)) > 0, 'and be called back'


def test_an_arriving_cluster_takes_its_whole_share_from_the_roles_above_theirs() -> None:
    """Kept shares let a cluster sit at its floor; a cluster with no servers yet is not one of them: it takes
    its whole proportional share at once, or it would never be covered."""
    fp, n = FlockParams(), 150
    xy, radii = np.array([[0.0, 0.0], [150.0, 0.0], [300.0, 0.0]]), np.full(3, 40.0)
    first = ClusterMap(xy, fp.height, radii)
    before = role_ids(first, n, fp)
    arrived = ClusterMap(np.r_[xy, [[300.0, 160.0]]], fp.height, np.r_[radii, 40.0], previous=first)
    after = role_ids(arrived, n, fp)
    share = layout.roles(arrived, fp.d).share
    assert abs(sum(r == 3 for r in after) - n * share[3]) <= 2.5, 'the whole proportional share'
    proportional = np.array(layout.roles(arrived, fp.d).demand) / sum(layout.roles(arrived, fp.d).demand)
    assert math.isclose(share[3], proportional[3], rel_tol=1e-9)
    assert all(before[i] == after[i] or after[i] in (3, (2, 3)) for i in range(n)), 'only towards the arrival'


def test_rule_nearest_staffs_an_arrival_from_the_clusters_nearest_it_on_the_tree() -> None:
    """Rule 'nearest': the MAPs an arriving cluster and its edge take come from the cluster the new edge joins,
    down to its floor, then from the next along the tree; without it, from the roles most above their share,
    wherever they are."""
    fp, n = FlockParams(), 150
    xy, radii = np.array([[0.0, 0.0], [150.0, 0.0], [300.0, 0.0]]), np.array([40.0, 30.0, 35.0])
    moved = {}
    for near in (True, False):
        first = ClusterMap(xy, fp.height, radii)
        before = role_ids(first, n, fp, near)
        arrived = ClusterMap(np.r_[xy, [[300.0, 160.0]]], fp.height, np.r_[radii, 15.0], previous=first)
        with switched_off(['cascade']):  # which keys pass, not where they end up: rule 'cascade' (below)
            after = role_ids(arrived, n, fp, near)
        assert all(b == a or a in (3, (2, 3)) for b, a in zip(before, after)), 'only towards the arrival'
        moved[near] = [sum(b == c and a != c for b, a in zip(before, after)) for c in range(3)]
        if near:
            roles = layout.roles(arrived, fp.d, True)
            proportional = np.array(roles.demand) / sum(roles.demand)
            assert math.isclose(roles.share[2], proportional[2] / (1 + layout.SLACK), rel_tol=1e-9), 'lent to its floor'
    # with the rule, the far end of the tree (cluster 0) lends what rounding leaves, and cluster 2 most
    assert moved[True][0] <= 1 < moved[False][0] and moved[True][2] > moved[False][2], moved
    assert moved[True][2] >= moved[True][1] > moved[True][0], moved


def far_moves(xy: np.ndarray, radii: np.ndarray, later: Callable[[ClusterMap], ClusterMap], n: int, fp: FlockParams,
              tree: set[tuple[int, int]]) -> tuple[dict[tuple[str, ...], int], dict[tuple[str, ...], collections.Counter]]:
    """With rule 'cascade' and without it, as a lagged vehicle lays roles out: how many of MAPs 0..n-1 change role
    across more than one hop of `tree` from the layout over clusters xy to the one `later` surveys after it, and
    how many MAPs each role has then."""
    def one_hop(b: Any, a: Any) -> bool:
        if not isinstance(b, int):
            return True  # a relay's keys move as they did
        return tuple(sorted((a, b))) in tree if isinstance(a, int) else b in a

    far, counts = {}, {}
    for rule_off in ((), ('cascade',)):
        with switched_off(rule_off):
            first = ClusterMap(xy, fp.height, radii)
            before = role_ids(first, n, fp, True)
            now = later(first)
            after = role_ids(now, n, fp, True)
        assert set(now.mst(now.live)) == tree, now.mst(now.live)
        far[rule_off] = sum(b != a and not one_hop(b, a) for b, a in zip(before, after))
        counts[rule_off] = collections.Counter(map(str, after))
    assert far[('cascade',)] >= 3, f'the case has no keys from two hops away to pass: {far}'
    return far, counts


@pytest.mark.parametrize('size', [15.0, 30.0])
def test_rule_cascade_passes_an_arrivals_keys_hop_by_hop(size: float) -> None:
    """Rule 'cascade': an arrival at the end of a line of three clusters, too large for its neighbour to staff
    alone and no larger than it (which has all of its own MAPs to pass on), takes the same shares as without the
    rule, but each MAP that changes role crosses one hop of the tree (to a neighbouring cluster, or onto an edge at
    its own cluster); without it, some cross two or three."""
    fp = FlockParams()
    xy, radii = np.array([[0.0, 0.0], [150.0, 0.0], [300.0, 0.0]]), np.array([40.0, 30.0, 35.0])
    far, counts = far_moves(xy, radii, lambda first: ClusterMap(np.r_[xy, [[300.0, 160.0]]], fp.height,
                                                                np.r_[radii, size], previous=first),
                            150, fp, {(0, 1), (1, 2), (2, 3)})
    assert far[()] <= 1, f'with the rule, MAPs from two hops away: {far[()]} (one may be what rounding leaves)'
    assert all(abs(counts[()][r] - counts[('cascade',)][r]) <= 1 for r in counts[()] | counts[('cascade',)]), counts


def test_rule_cascade_flies_over_a_cluster_that_gave_an_arrival_all_its_own() -> None:
    """Rule 'cascade' where the arrival is larger than its neighbour: the neighbour's own MAPs all go to the arrival,
    so the new edge's cannot pass through it. They pass through the clusters beyond that still hold their own,
    each MAP crossing two hops at most, not straight from the far end of the tree three hops off (arrival layout
    6, seed 1, of studies/vehicle.yaml: five relays crossed 350 m of lattices and the chain stood 40 s late)."""
    fp, n = FlockParams(), 150
    xy, radii = np.array([[0.0, 0.0], [150.0, 0.0], [300.0, 0.0]]), np.array([40.0, 30.0, 35.0])
    tree = {(0, 1), (1, 2), (2, 3)}
    first = ClusterMap(xy, fp.height, radii)
    before = role_ids(first, n, fp, True)
    now = ClusterMap(np.r_[xy, [[300.0, 160.0]]], fp.height, np.r_[radii, 45.0], previous=first)
    after = role_ids(now, n, fp, True)
    assert set(now.mst(now.live)) == tree

    def hops(b: Any, a: Any) -> int:
        if not isinstance(a, int):
            return 1 + min(hops(b, end) for end in a)
        return len(layout.path(now, b, a)) - 1

    crossed = collections.Counter(hops(b, a) for b, a in zip(before, after) if b != a and isinstance(b, int))
    assert crossed[2] > 0, f'the case has nothing to pass over a cluster that gave all its own: {crossed}'
    assert max(crossed) == 2, f'MAPs crossing three hops or more: {crossed}'


def test_rule_cascade_passes_a_new_edges_keys_hop_by_hop_when_a_drifting_cluster_changes_the_tree() -> None:
    """Rule 'cascade' beyond arrivals: cluster 1 drifts until the tree swaps edge (0, 1) for (2, 3), which stands
    while the new edge takes its share from the clusters nearest it (rule 'nearest'). The servers of 2 and 3 go
    down to their floors, and what the edge lacks comes from clusters 0 and 1, two hops from it: with the rule 2
    and 3 give their own and take 0's and 1's, so each MAP that changes role crosses one hop; without it, servers
    of 0 and 1 fly to the new edge across their neighbours' lattices. The shares are the same."""
    fp = FlockParams()
    radii = np.full(4, 30.0)
    xy = np.array([[0.0, 0.0], [160.0, 0.0], [0.0, 150.0], [170.0, 150.0]])
    moved = xy.copy()
    moved[1] = [175.0, 0.0]  # the tree swaps (0, 1) for (2, 3)
    far, counts = far_moves(xy, radii, lambda first: ClusterMap(moved, fp.height, radii, previous=first), 160, fp,
                            {(0, 2), (1, 3), (2, 3)})
    assert far[()] == 0, f'with the rule, MAPs from two hops away: {far[()]}'
    assert counts[()] == counts[('cascade',)], counts


def test_an_edge_that_leaves_the_tree_keeps_its_chain_while_the_new_one_is_staffed_from_the_surplus() -> None:
    """Cluster 1 drifts until the tree swaps edge (0, 1) for (2, 3), which shares no cluster with it: no
    relay can swing. The old chain stands for STANDING surveys while servers with keys to spare staff the new
    one, so the two halves stay joined; then its relays join clusters 0 and 1, each the nearer end, flying
    straight along their chain."""
    fp, n = FlockParams(), 160
    radii = np.full(4, 30.0)
    xy = np.array([[0.0, 0.0], [160.0, 0.0], [0.0, 150.0], [170.0, 150.0]])
    first = ClusterMap(xy, fp.height, radii)
    moved = xy.copy()
    moved[1] = [175.0, 0.0]
    maps = [first]
    for _ in range(layout.STANDING + 1):
        maps.append(ClusterMap(moved, fp.height, radii, previous=maps[-1]))
        layout.roles(maps[-1], fp.d)  # laid out before the next survey drops the one it carries from
    assert layout.roles(first, fp.d).edges == ((0, 1), (0, 2), (1, 3))
    assert maps[1].mst(maps[1].live) == ((0, 2), (1, 3), (2, 3)), 'the tree swapped (0, 1) for (2, 3)'
    ids = [[i for i in range(n) if role_ids(m, n, fp)[i] == r] for m in maps for r in [(0, 1)]]
    relays = ids[0]
    assert len(relays) >= 4
    before, during = role_ids(first, n, fp), role_ids(maps[1], n, fp)
    assert layout.roles(maps[1], fp.d).standing == (((0, 1), layout.STANDING),)
    joined = [i for i in range(n) if during[i] == (2, 3)]
    assert len(joined) >= 4 and all(isinstance(before[i], int) for i in joined), \
        'the new edge is staffed by servers the clusters lend, not by the relays of the old one'
    assert abs(len(joined) - n * layout.roles(maps[1], fp.d).share[layout.roles(maps[1], fp.d).index((2, 3))]) <= 2.5, \
        'at its whole share at once'
    for m in maps[1:-1]:
        assert ids[maps.index(m)] == relays, 'the old chain stands'
    q = np.array([80.0, 0.0, fp.height])
    mem = demand_switch(Mine(mode=M1, goal=0, bridge=(0, 1), settled=True), relays[0], 0.0, q, maps[-2], fp)
    assert mem.mode == M1 and mem.bridge == (0, 1), 'its relay keeps bridging it'
    last_before, last = role_ids(maps[-2], n, fp), role_ids(maps[-1], n, fp)
    assert layout.roles(maps[-1], fp.d).edges == ((0, 2), (1, 3), (2, 3)), 'then the old edge is released'
    old = layout.roles(maps[-2], fp.d)
    for i in relays:
        near = 0 if old.place(key_of(i), old.index((0, 1))) < 0.5 else 1
        assert last[i] == near, f'relay {i} joins the nearer end of its chain'
    assert [i for i in range(n) if last[i] != last_before[i]] == relays, 'and nobody else changes role'
    a, b = maps[-1].xy[0], maps[-1].xy[1]
    for i in relays:  # on its chain, beside the far cluster: straight along the chain, not round the tree
        at = b + (a - b) * 0.25 if last[i] == 0 else a + (b - a) * 0.25
        q = np.array([*at, fp.height])
        mem = demand_switch(Mine(mode=M1, goal=0, bridge=(0, 1), settled=True), i, 0.0, q, maps[-1], fp)
        assert mem.goal == last[i] and mem.transit and mem.straight
        assert en_route(mem, q, maps[-1], fp) == NO_GOAL
        assert en_route(mem._replace(straight=False), q, maps[-1], fp) != NO_GOAL, 'the tree would go round'
    # On a multirotor a released relay flies the tree like any MAP in transit: straight along its chain it was cut off
    # (rule 'straight', docs/vehicle.md).
    multirotor = replace(fp, **vehicle.MULTIROTOR.envelope())
    with switched_off(['nearest', 'cascade']):  # the multirotor's rules of the shares, which the tree here does not need
        released = [demand_switch(Mine(mode=M1, goal=0, bridge=(0, 1), settled=True), i, 0.0, q, maps[-1], multirotor)
                    for i in relays]
    assert any(m.mode != M1 and m.transit for m in released) and not any(m.straight for m in released)
