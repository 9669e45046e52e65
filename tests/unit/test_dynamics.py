"""Users that move: the crowd's motion, the online survey's stable ids, and MAPs whose cluster left."""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from uav_agent.core.allocations.algorithm2 import mode_switch
from uav_agent.core.clusters import NO_GOAL, ClusterMap, key_of
from uav_agent.core.allocations.demand import keys, layout
from uav_agent.core.allocations.demand.allocation import demand_switch, en_route, pivot, swing_place
from uav_agent.core.allocations.demand.memory import Mine
from uav_agent.core.policies import reference
from uav_agent.core.state import M0, M1, M2, Memory
from uav_agent.core.params import FlockParams
from uav_flock_tools.batch import BatchSimulator
from world_sim.core.crowd import center_at
from world_sim.core.scenario import Cluster, ScenarioError, parse
from world_sim.core.survey import NONE, find_clusters, settle, survey


def blobs(rng: np.random.Generator, centres: np.ndarray, size: int = 200, spread: float = 10.0) -> np.ndarray:
    return np.concatenate([rng.normal(c, spread, size=(size, 2)) for c in centres])


# Cluster centres on a 150 m grid, so any two are far apart next to their spread, in any number.
CENTRES = st.lists(st.tuples(st.integers(-4, 4), st.integers(-4, 4)), min_size=1, max_size=6, unique=True)


@settings(max_examples=40, deadline=None)
@given(CENTRES, st.lists(st.tuples(st.floats(-8, 8), st.floats(-8, 8)), min_size=6, max_size=6), st.integers(0, 99))
def test_survey_ids_follow_clusters_that_drift(cells: list[tuple[int, int]], v: list[tuple[float, float]],
                                               seed: int) -> None:
    """Every cluster moving at up to 8 m/s for one 2 s period keeps its id, and its velocity is measured."""
    rng = np.random.default_rng(seed)
    centres = np.array(cells, dtype=float) * 150.0
    before = blobs(rng, centres)
    tracks, labels = survey(before, None, 2.0)
    shift = np.array(v[:len(centres)]) * 2.0
    after = before + np.repeat(shift, 200, axis=0)
    moved, labels2 = survey(after, tracks, 2.0)
    assert len(moved.sizes) == len(centres), 'no cluster was taken for a new one'
    ids = [int(np.bincount(labels[k * 200:(k + 1) * 200][labels[k * 200:(k + 1) * 200] >= 0]).argmax())
           for k in range(len(centres))]
    for k, i in enumerate(ids):
        mine = labels2[k * 200:(k + 1) * 200]
        assert np.mean(mine == i) > 0.9, f'cluster {k} kept id {i}'
        assert np.allclose(moved.velocities[i], shift[k] / 2.0, atol=0.5)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(10.0, 15.0), st.floats(10.0, 15.0), st.integers(300, 800),
       st.integers(300, 800))
def test_survey_keeps_two_dense_clusters_100_m_apart(seed: int, sa: float, sb: float, na: int, nb: int) -> None:
    """Two clusters of sigma 10-15 m and 300-800 MSDs, centres 100 m apart, are two: the thin tails between
    them must not chain them into one, centred on empty ground (with 5 MSDs to a core point they did).
    Wider and denser pairs, which random layouts also draw, can still chain (sigma 16-18 m with 800 MSDs
    each: 0.3 to 15 % of draws; docs/dynamics.md)."""
    rng = np.random.default_rng(seed)
    xy = np.concatenate([rng.normal((0.0, 0.0), sa, size=(na, 2)), rng.normal((100.0, 0.0), sb, size=(nb, 2))])
    tracks, _ = survey(xy, None, 2.0)
    assert int(tracks.active.sum()) == 2, f'{int(tracks.active.sum())} clusters found in two drawn 100 m apart'


@settings(max_examples=30, deadline=None)
@given(CENTRES, st.integers(0, 99))
def test_survey_gives_an_arrival_a_new_id_and_keeps_an_ended_clusters_id(cells: list[tuple[int, int]],
                                                                         seed: int) -> None:
    rng = np.random.default_rng(seed)
    centres = np.array(cells, dtype=float) * 150.0
    first, _ = survey(blobs(rng, centres), None, 2.0)
    newcomer = np.array([[1000.0, 1000.0]])
    grown, labels = survey(blobs(rng, np.vstack([centres[1:], newcomer])), first, 2.0)
    assert len(grown.sizes) == len(centres) + 1, 'the arrival took a new id'
    assert np.all(labels[-200:][labels[-200:] != NONE] == len(centres))
    assert grown.sizes[0] == 0 and not grown.active[0], 'the first cluster left: its id ended, not reused'
    assert np.allclose(grown.centroids[1:len(centres)], first.centroids[1:], atol=5.0), 'the others kept theirs'


def test_settle_reports_a_cluster_again_only_when_it_changed_enough() -> None:
    rng = np.random.default_rng(0)
    xy = blobs(rng, np.array([[0.0, 0.0], [200.0, 0.0]]))
    first, _ = survey(xy, None, 2.0)
    jittered, _ = survey(xy + rng.normal(0.0, 0.3, xy.shape), first, 2.0)
    assert settle(first, jittered).same(first), 'wandering users do not change the report'
    moved, _ = survey(xy + np.r_[np.zeros((200, 2)), np.tile([5.0, 0.0], (200, 1))], first, 2.0)
    report = settle(first, moved)
    assert np.array_equal(report.centroids[0], first.centroids[0]) and report.centroids[1, 0] > first.centroids[1, 0] + 4


def test_a_cluster_follows_its_waypoints_then_holds() -> None:
    c = Cluster((0.0, 0.0), 10.0, 100, waypoints=((30.0, 0.0), (30.0, 40.0)), speed=2.0, start=5.0)
    assert np.allclose(center_at(c, 3.0), [0.0, 0.0]), 'still before it starts'
    assert np.allclose(center_at(c, 5.0 + 10.0), [20.0, 0.0])
    assert np.allclose(center_at(c, 5.0 + 25.0), [30.0, 20.0])
    assert np.allclose(center_at(c, 500.0), [30.0, 40.0])


def test_a_map_whose_cluster_left_takes_another_role() -> None:
    fp = FlockParams()
    xy, radii = np.array([[0.0, 0.0], [150.0, 0.0], [0.0, 150.0]]), np.array([30.0, 30.0, 30.0])
    everyone = ClusterMap(xy, fp.height, radii)
    mine = next(i for i in range(200) if layout.roles(everyone, fp.d).of(key_of(i)) == 1)
    mem = demand_switch(Mine(), mine, 0.0, np.array([150.0, 0.0, 20.0]), everyone, fp)
    assert mem.goal == 1 and mem.mode == M0
    left = ClusterMap(xy, fp.height, radii, active=np.array([True, False, True]))
    after = demand_switch(mem._replace(mode=M2, achieved=0b010), mine, 0.0, np.array([150.0, 0.0, 20.0]), left, fp)
    assert after.goal != 1 and (after.mode == M1 and 1 not in after.bridge or after.mode == M0 and after.goal in (0, 2))
    paper = dataclasses.replace(fp, allocation='algorithm2')
    stranded = mode_switch(Memory(mode=M2, goal=1, achieved=0b010), 0, 0.0, np.array([150.0, 0.0, 20.0]), left, paper)
    assert stranded.mode == M0 and stranded.goal in (0, 2), 'Algorithm 2 sends it to the nearest cluster left'
    nothing = ClusterMap(xy, fp.height, radii, active=np.zeros(3, dtype=bool))
    idle = demand_switch(after, mine, 0.0, np.array([150.0, 0.0, 20.0]), nothing, fp)
    assert idle.goal == NO_GOAL and idle.mode == M2, 'with no cluster at all it holds where it is'


def test_users_that_stand_still_are_never_moved_or_resurveyed(paper_scenario_path: str) -> None:
    sim = BatchSimulator(parse(yaml.safe_load(Path(paper_scenario_path).read_text())).with_overrides(duration=3.0))
    before = sim.world.users
    sim.run()
    assert sim.world.users is before and sim.world.clusters_version == 0 and sim.result().motion is None


@pytest.mark.parametrize('edit, key', [
    (lambda c: c.__setitem__('velocity', [1.0]), 'users.clusters[0].velocity'),
    (lambda c: c.__setitem__('waypoints', [[1.0, 2.0]]), 'users.clusters[0].speed'),
    (lambda c: c.update(waypoints=[[1.0, 2.0]], speed=2.0, velocity=[1.0, 0.0]), 'users.clusters[0].waypoints'),
    (lambda c: c.__setitem__('speed', -2.0) or c.__setitem__('waypoints', [[0, 0]]), 'users.clusters[0].speed'),
    (lambda c: c.update(start=10.0, end=5.0), 'users.clusters[0].end'),
    (lambda c: c.__setitem__('walk', -0.5), 'users.clusters[0].walk'),
    (lambda c: c.__setitem__('start', 'soon'), 'users.clusters[0].start'),
])
def test_bad_motion_keys_name_the_key(paper_scenario_path: str, edit: Any, key: str) -> None:
    doc = yaml.safe_load(Path(paper_scenario_path).read_text())
    edit(doc['users']['clusters'][0])
    with pytest.raises(ScenarioError) as err:
        parse(doc)
    assert str(err.value).startswith(key + ':'), str(err.value)


def test_survey_mode_is_checked(paper_scenario_path: str) -> None:
    doc = yaml.safe_load(Path(paper_scenario_path).read_text())
    doc['users']['survey'] = 'sometimes'
    with pytest.raises(ScenarioError, match=r'^users.survey:'):
        parse(doc)


def test_a_map_in_transit_to_a_new_role_flies_along_the_tree() -> None:
    """A MAP that leaves a settled place for a new role passes the clusters between, where relays are."""
    fp = FlockParams()
    xy = np.array([[0.0, 0.0], [100.0, 0.0], [200.0, 0.0], [100.0, 120.0]])  # tree: 0-1, 1-2, 1-3
    clusters = ClusterMap(xy, fp.height, np.full(4, 25.0))
    at_0 = np.array([5.0, 3.0, 20.0])
    moving = Mine(mode=M0, goal=2, settled=True, transit=True).memory()
    ref = reference(moving, 7, at_0, np.zeros((0, 3)), [], clusters, fp)
    assert np.allclose(ref.target[:2], xy[1]), 'from cluster 0 to 2 it heads for cluster 1 first'
    first_flight = reference(Mine(mode=M0, goal=2).memory(), 7, at_0, np.zeros((0, 3)), [],
                             clusters, fp)
    assert np.allclose(first_flight.target[:2], xy[2]), 'before it ever settled it flies straight, as always'
    near_2 = reference(moving, 7, np.array([160.0, 0.0, 20.0]), np.zeros((0, 3)), [], clusters, fp)
    assert np.allclose(near_2.target[:2], xy[2]), 'once its goal is the nearest cluster it flies to it'


def test_a_map_in_transit_leaves_its_cluster_by_the_start_of_the_relay_chain() -> None:
    """From the far side of its disc, a MAP in transit first joins the chain's line where the chain starts,
    then flies along it to the next cluster; past that point it never turns back. Towards a cluster not yet
    served there is no chain to join: it flies straight."""
    fp = FlockParams()
    xy = np.array([[0.0, 0.0], [100.0, 0.0], [200.0, 0.0], [100.0, 120.0]])  # tree: 0-1, 1-2, 1-3
    clusters = ClusterMap(xy, fp.height, np.full(4, 25.0))
    moving = Mine(mode=M0, goal=2, settled=True, transit=True, achieved=0b1111).memory()

    def aim(x: float, y: float, mem: Memory = moving) -> np.ndarray:
        return reference(mem, 7, np.array([x, y, 20.0]), np.zeros((0, 3)), [], clusters, fp).target[:2]

    assert np.allclose(aim(-15.0, -18.0, moving._replace(achieved=0b1101)), xy[1]), 'cluster 1 not served yet'

    assert np.allclose(aim(-15.0, -18.0), [25.0, 0.0]), 'far side of the disc: to where chain (0, 1) starts'
    assert np.allclose(aim(10.0, 20.0), [25.0, 0.0]), 'beside the line, short of the chain: to its start'
    assert np.allclose(aim(20.0, 4.0), xy[1]), 'on the line: along it to cluster 1'
    assert np.allclose(aim(40.0, 20.0), xy[1]), 'past the start of the chain: on, not back'
    assert np.allclose(aim(110.0, 30.0), [125.0, 0.0]), 'at cluster 1, beside chain (1, 2): to its start'


def test_relays_whose_edge_leaves_the_tree_swing_about_the_cluster_it_shares_with_the_new_one() -> None:
    """Cluster 2 drifts until the tree swaps edge (1, 2) for (0, 2): each relay of (1, 2) that is given
    (0, 2) keeps its place from cluster 2, so the chain swings about 2 and its far end slides along (0, 1)."""
    fp, n = FlockParams(), 150
    radii = np.full(3, 25.0)
    before = ClusterMap(np.array([[0.0, 0.0], [150.0, 0.0], [200.0, 120.0]]), fp.height, radii)
    after = ClusterMap(np.array([[0.0, 0.0], [150.0, 0.0], [60.0, 140.0]]), fp.height, radii, previous=before)
    assert layout.roles(before, fp.d).edges == ((0, 1), (1, 2)) and layout.roles(after, fp.d).edges == ((0, 1), (0, 2))
    old, new = role_ids(before, n, fp), role_ids(after, n, fp)
    swung = [i for i in range(n) if old[i] == (1, 2) and new[i] == (0, 2)]
    assert len(swung) >= 3, 'the new edge takes the keys of the one that left'
    a, b = after.xy[1], after.xy[2]  # where the old edge runs now: cluster 2 has moved
    length, rim = float(np.linalg.norm(b - a)), 25.0 - fp.d / 2
    origin, u, _ = after.axis((0, 2))
    start, stop = after.gap((0, 2), fp.d / 2)
    far = 0
    for i, f in zip(swung, np.linspace(0.0, 1.0, len(swung))):
        at = a + (rim + f * (length - 2 * rim)) * (b - a) / length  # f of the way along the old gap from 1
        q = np.array([*at, fp.height])
        settled = Mine(mode=M1, goal=1, bridge=(1, 2), settled=True)
        p, g = pivot(settled, q, (0, 2), after, fp)
        assert p == 2 and abs(g - (1.0 - f)) < 1e-6, 'its place along the old gap, counted from cluster 2'
        place = swing_place((p, g), (0, 2), after, fp)
        assert abs(place - (stop - g * (stop - start))) < 1e-6, 'the same place along the new gap from 2'
        mem = demand_switch(settled, i, 0.0, q, after, fp)
        assert mem.mode == M1 and mem.bridge == (0, 2)
        if np.linalg.norm(origin + u * place - at) <= fp.d:
            assert mem.swing is None, 'already at its new place: nothing to swing'
            continue
        far += 1
        assert mem.swing == (p, g)
        assert en_route(mem, q, after, fp) == NO_GOAL, 'a swinging relay flies straight to its new place'
        ref = reference(mem.memory(), i, q, np.zeros((0, 3)), [], after, fp)
        assert np.allclose((ref.q1[:2] + ref.q2[:2]) / 2, origin + u * place), 'it aims there'
    assert far >= 2
    there = after.xy[0] + (after.xy[2] - after.xy[0]) * 0.5
    done = Mine(mode=M1, goal=0, bridge=(0, 2), settled=True, swing=(2, 0.5))
    assert demand_switch(done, swung[0], 0.0, np.array([*there, fp.height]), after, fp).swing is None, \
        'at its new place the swing ends and the chain rule takes over'


def test_only_a_settled_relay_whose_edges_share_one_cluster_swings() -> None:
    fp = FlockParams()
    clusters = ClusterMap(np.array([[0.0, 0.0], [150.0, 0.0], [60.0, 140.0], [300.0, 50.0]]), fp.height,
                          np.full(4, 25.0))
    q = np.array([75.0, 0.0, fp.height])
    settled = Mine(mode=M1, goal=0, bridge=(0, 1), settled=True)
    assert pivot(settled, q, (0, 2), clusters, fp) == (0, pytest.approx(0.5))
    assert pivot(settled, q, (2, 3), clusters, fp) is None, 'no cluster in common: it flies along the tree'
    assert pivot(settled._replace(settled=False), q, (0, 2), clusters, fp) is None, 'first out: no chain yet'
    assert pivot(Mine(mode=M0, goal=0, settled=True), q, (0, 2), clusters, fp) is None, 'a server'
    gone = ClusterMap(clusters.xy, fp.height, np.full(4, 25.0), active=np.array([True, False, True, True]))
    assert pivot(settled, q, (0, 2), gone, fp) is None, 'its old edge ended with its cluster: nothing to swing'


def role_ids(clusters: ClusterMap, n: int, fp: FlockParams) -> list[Any]:
    """Each of MAPs 0..n-1's role as a cluster id or an edge: what stays the same across surveys."""
    roles = layout.roles(clusters, fp.d)
    return [[*range(clusters.count), *roles.edges][roles.of(key_of(i))] for i in range(n)]


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


def without_lineage(before: ClusterMap, after: ClusterMap, n: int, fp: FlockParams) -> list[Any]:
    """Roles as keys.carry lays them out when nothing tells it which cluster continues which."""
    new, ids = layout.roles(after, fp.d), [*range(after.count), *layout.roles(after, fp.d).edges]
    pieces = keys.carry(layout.roles(before, fp.d).pieces, dict(zip(ids, new.share)))
    return [r for i in range(n) for lo, hi, r in pieces if lo <= key_of(i) < hi]


def test_when_two_clusters_merge_the_servers_over_them_keep_serving_them() -> None:
    """The survey keeps one id of two clusters that merge and ends the other. The ended cluster's servers
    are over the merged users: they serve the cluster that goes on, which draws nobody from elsewhere
    while they cover its growth."""
    fp, n = FlockParams(), 150
    xy = np.array([[0.0, 0.0], [300.0, 0.0], [50.0, 0.0], [300.0, 200.0]])  # 0 and 2 apart on the key line
    before = ClusterMap(xy, fp.height, np.array([30.0, 30.0, 30.0, 30.0]))
    merged = xy.copy()
    merged[0] = [25.0, 0.0]
    after = ClusterMap(merged, fp.height, np.array([42.0, 30.0, 30.0, 30.0]), active=np.array([True, True, False, True]),
                       previous=before)
    old, new = role_ids(before, n, fp), role_ids(after, n, fp)
    over = {i for i in range(n) if old[i] in (0, 2, (0, 2))}
    assert {i for i in range(n) if new[i] == 0} <= over, 'nobody flies in from another role'
    assert {i for i in range(n) if old[i] == 0} <= {i for i in range(n) if new[i] == 0}, 'its own servers stay'
    assert sum(new[i] == 0 for i in range(n)) > sum(old[i] == 0 for i in range(n)), 'it grew by servers of 2'
    blind = without_lineage(before, after, n, fp)
    assert any(blind[i] == 0 for i in range(n) if i not in over), 'without lineage, others would fly in'


def test_when_a_cluster_splits_the_part_that_moves_off_is_served_by_the_servers_of_the_whole() -> None:
    """The part of a split cluster that takes a new id is staffed from the cluster it split from, whose
    servers are over it, not from the other roles' keys wherever those MAPs are."""
    fp, n = FlockParams(), 150
    xy = np.array([[0.0, 0.0], [300.0, 0.0], [300.0, 200.0]])
    before = ClusterMap(xy, fp.height, np.array([45.0, 30.0, 30.0]))
    split = np.array([[-25.0, 0.0], [300.0, 0.0], [300.0, 200.0], [25.0, 0.0]])
    after = ClusterMap(split, fp.height, np.array([30.0, 30.0, 30.0, 30.0]), previous=before)
    old, new = role_ids(before, n, fp), role_ids(after, n, fp)
    part = {i for i in range(n) if new[i] == 3}
    assert part and all(old[i] == 0 for i in part), 'the new part is served by servers of the whole'
    blind = without_lineage(before, after, n, fp)
    assert any(old[i] != 0 for i in range(n) if blind[i] == 3), 'without lineage, others would fly in'


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


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(10.0, 16.0), st.floats(10.0, 16.0), st.integers(200, 700),
       st.integers(200, 700), st.floats(1.0, 4.0), st.floats(-1.0, 1.0))
def test_two_crowds_that_meet_stay_two_clusters(seed: int, sa: float, sb: float, na: int, nb: int, speed: float,
                                               offset: float) -> None:
    """Two crowds that walk into and through each other are two tracked clusters at every 2 s survey, and
    each crowd is one of them once they are apart again. DBSCAN alone finds them as one while their tails
    touch, and the tracker ended one id (docs/dynamics.md, "Crowds that meet stay two")."""
    rng = np.random.default_rng(seed)
    a, b = rng.normal(0.0, sa, size=(na, 2)), rng.normal(0.0, sb, size=(nb, 2))
    ca, cb = np.array([0.0, 0.0]), np.array([200.0, offset * sa])  # offset: how far off head-on, up to one sigma
    va, vb = np.array([speed, 0.0]), np.array([-speed, 0.0])
    tracks, merged_by_dbscan = None, 0
    for k in range(int(400.0 / (2 * speed) / 2.0) + 1):  # until they are as far apart on the other side
        t = 2.0 * k
        xy = np.concatenate([a + ca + va * t, b + cb + vb * t])
        tracks, labels = survey(xy, tracks, 2.0)
        assert int(tracks.active.sum()) == 2, f't = {t:g} s: {int(tracks.active.sum())} clusters, not 2'
        merged_by_dbscan += int(find_clusters(xy).max()) + 1 < 2
    assert merged_by_dbscan > 0, 'the crowds never met, so nothing was tested'
    la, lb = labels[:na][labels[:na] != NONE], labels[na:][labels[na:] != NONE]  # DBSCAN leaves stragglers out
    ia, ib = np.bincount(la).argmax(), np.bincount(lb).argmax()
    assert ia != ib and np.mean(la == ia) > 0.9 and np.mean(lb == ib) > 0.9, 'apart again, each crowd is one cluster'
