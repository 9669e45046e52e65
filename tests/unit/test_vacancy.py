"""Roles emptied by failures (core/allocations/demand/vacancy.py): noticed from gossip alone, and re-staffed from the survivors."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from uav_agent.core.clusters import ClusterMap, key_of
from uav_agent.core.params import FlockParams
from uav_agent.core.allocations.demand import keys, layout
from uav_agent.core.allocations.demand.allocation import demand_switch
from uav_agent.core.allocations.demand.chain import TAUT_STEPS, chain_of, tally, taut
from uav_agent.core.allocations.demand.memory import Mine
from uav_agent.core.state import M1, M2, NOBODY, Near, Told
from uav_agent.core.ablation import switched_off
from uav_agent.core.allocations.demand.vacancy import PATIENT_STEPS, VACANT_STEPS, code, gossip, vacate, vanished, view
from uav_flock_tools.batch import BatchSimulator
from world_sim.core import layouts
from world_sim.core.scenario import load

P = FlockParams()
MULTIROTOR = dataclasses.replace(P, v_max=15.0, a_max=4.0, tau=0.3)  # a lagged vehicle (envelope.limited)
# Three clusters in a row, 100 m apart: roles 0, 1, 2 (servers) and the edges (0, 1), (1, 2) (relays).
ROW = ClusterMap(np.array([[0.0, 0.0], [100.0, 0.0], [200.0, 0.0]]), P.height, radii=np.array([25.0, 25.0, 25.0]))
ROLES = layout.roles(ROW, P.d)
ALL = (0, 1, 2, (0, 1), (1, 2))
NOW = 500


def heard(at: dict[object, int]) -> tuple[tuple[int, int], ...]:
    return tuple(sorted((code(r), k) for r, k in at.items()))


def near_cluster_2() -> np.ndarray:
    return np.array([180.0, 0.0, P.height])  # in cluster 2's disc, on the side of edge (1, 2)


def relay_of_edge_12(**kw: object) -> Mine:
    return Mine(mode=M1, goal=1, bridge=(1, 2), settled=True, since=100, **kw)  # type: ignore[arg-type]


def test_gossip_keeps_the_latest_step_of_each_role_and_the_union_of_lost_keys() -> None:
    mine = Mine(mode=M2, goal=0, seen=heard({0: 3, 1: 7}), lost=((0.1, 0.2),), short=((65, 1),))
    out = gossip(mine, 9, [heard({1: 5, 2: 8})], [((0.15, 0.3),), ((0.5, 0.6),)], [((65, 2), (130, 1))])
    assert dict(out.seen) == {0: 9, 1: 7, 2: 8}  # own role: heard now
    assert out.lost == ((0.1, 0.3), (0.5, 0.6))
    assert out.short == ((65, 2), (130, 1)), 'the larger shortage of each role'


def test_a_role_emptied_by_failures_is_restaffed_from_the_survivors() -> None:
    """Cluster 2's servers are silent for longer than VACANT_STEPS: a relay at cluster 2 declares their keys
    lost, and cluster 2's share is laid over survivors' keys again."""
    at = {r: NOW for r in ALL} | {2: NOW - VACANT_STEPS - 1}
    mem = vacate(relay_of_edge_12(seen=heard(at)), NOW, near_cluster_2(), ROW, P)
    servers_2 = [(lo, hi) for lo, hi, r in ROLES.pieces if r == 2]
    assert mem.lost == keys.united(servers_2), 'the silent role\'s keys are known lost'
    assert dict(mem.seen)[2] == NOW + VACANT_STEPS, 'its new members get twice VACANT_STEPS to arrive'
    after = view(ROLES, mem.lost)
    held = keys.totals(after.pieces)
    assert math.isclose(held[2], ROLES.share[2], abs_tol=1e-9), 'cluster 2 holds its share of the survivors\' keys'
    n = 60
    survivors = [i for i in range(n) if not any(lo <= key_of(i) < hi for lo, hi in mem.lost)]
    to_2 = [i for i in survivors if after.of(keys.squeeze(key_of(i), mem.lost)) == 2]
    assert len(to_2) >= math.floor(ROLES.share[2] * len(survivors)), (len(to_2), ROLES.share[2] * len(survivors))
    moved = [i for i in survivors if after.of(keys.squeeze(key_of(i), mem.lost)) != ROLES.of(key_of(i))]
    assert sorted(moved) == sorted(to_2), 'only the MAPs that restaff cluster 2 change role'


def test_on_a_multirotor_a_role_goes_unheard_for_patient_steps_before_it_is_declared() -> None:
    """Rule 'patient': a multirotor's MAPs take 10-20 s to cross to a role, so a role silent for longer than
    VACANT_STEPS but not PATIENT_STEPS is still on its way; the paper's vehicle declares it lost."""
    assert PATIENT_STEPS > VACANT_STEPS
    quiet = {r: NOW for r in ALL} | {2: NOW - VACANT_STEPS - 1}
    assert vacate(relay_of_edge_12(seen=heard(quiet)), NOW, near_cluster_2(), ROW, P).lost != ()
    assert vacate(relay_of_edge_12(seen=heard(quiet)), NOW, near_cluster_2(), ROW, MULTIROTOR).lost == ()
    with switched_off(['patient']):
        assert vacate(relay_of_edge_12(seen=heard(quiet)), NOW, near_cluster_2(), ROW, MULTIROTOR).lost != ()
    silent = {r: NOW for r in ALL} | {2: NOW - PATIENT_STEPS - 1}
    mem = vacate(relay_of_edge_12(seen=heard(silent)), NOW, near_cluster_2(), ROW, MULTIROTOR)
    assert mem.lost != () and dict(mem.seen)[2] == NOW + PATIENT_STEPS


def test_a_map_cut_off_alone_or_away_from_the_role_declares_nothing() -> None:
    alone = {(1, 2): NOW} | {r: NOW - VACANT_STEPS - 1 for r in ALL if r != (1, 2)}
    assert vacate(relay_of_edge_12(seen=heard(alone)), NOW, near_cluster_2(), ROW, P).lost == ()
    quiet_2 = {r: NOW for r in ALL} | {2: NOW - VACANT_STEPS - 1}
    far = np.array([20.0, 0.0, P.height])  # at cluster 0, 180 m from cluster 2
    assert vacate(relay_of_edge_12(seen=heard(quiet_2)), NOW, far, ROW, P).lost == ()


def test_a_role_not_heard_since_the_map_reached_its_place_is_not_declared() -> None:
    """While the formation forms, a role's MAPs may still be elsewhere: only a role that was there can be lost."""
    before = {r: NOW for r in ALL} | {2: 90}  # heard last before this MAP settled (since = 100)
    mem = relay_of_edge_12(seen=heard(before))
    assert vacate(mem, NOW, near_cluster_2(), ROW, P).lost == ()
    assert vacate(mem._replace(since=-1), NOW, near_cluster_2(), ROW, P).lost == (), 'never settled: nothing'


@pytest.mark.slow
def test_a_wiped_out_cluster_is_served_again_in_a_batch_run(paper_scenario_path: str) -> None:
    """Every server of one cluster fails at once: the survivors learn it by gossip, and some take the role."""
    paper = load(paper_scenario_path)
    lay = layouts.draw(paper, layouts.LayoutSpec(), np.random.default_rng(7))
    lay = dataclasses.replace(lay, flock=dataclasses.replace(lay.flock, **{
        k: getattr(FlockParams(), k) for k in ('allocation', 'edge_choice')}))  # the default policies
    s = dataclasses.replace(lay, maps=math.ceil(1.8 * layouts.floor(lay).total), duration=70.0)
    sim = BatchSimulator(s)
    wiped: list[int] = []
    for _ in range(s.steps):
        if sim.world.k == 300:
            wiped = [i for i in range(s.maps) if sim.memory[i].mode != M1 and sim.memory[i].goal == 0]
            assert wiped, 'cluster 0 must have servers to lose'
            sim.world.drop(np.array(wiped))
        sim.step()
    live = np.flatnonzero(sim.alive).tolist()
    assert [i for i in live if sim.memory[i].mode != M1 and sim.memory[i].goal == 0], 'nobody serves cluster 0 again'
    assert {Mine.of(sim.memory[i]).lost for i in live} == {Mine.of(sim.memory[live[0]]).lost} != (), 'every MAP squeezes the same keys'
    assert all(any(lo <= key_of(i) < hi for lo, hi in Mine.of(sim.memory[live[0]]).lost) for i in wiped)


def chain_heard(*xs: tuple[float, int]) -> Near:
    """Neighbours on the x axis at flight height: (x, cluster each serves)."""
    return Near(np.array([[x, 0.0, P.height] for x, _ in xs]).reshape(-1, 3), [Told(M2, k, None) for _, k in xs])


def test_a_chain_is_taut_when_its_links_outgrow_what_holds_or_it_no_longer_reaches_across() -> None:
    """A relay of edge (1, 2) midway, at x = 150: cluster 1's servers reach to x = 125, cluster 2's from 175."""
    relay = relay_of_edge_12(seen=heard({r: 400 for r in ALL}))
    here = np.array([150.0, 0.0, P.height])

    def is_taut(mem: Mine, near: Near) -> bool:
        assert mem.bridge is not None
        return taut(mem, chain_of(here, mem.bridge, near.q, near.told, ROW, P), P)

    assert is_taut(relay, chain_heard((124.0, 1), (176.0, 2))), 'links of 26 m: past (d + r) / 2'
    assert not is_taut(relay, chain_heard((130.0, 1), (170.0, 2))), 'links of 20 m hold'
    assert is_taut(relay, chain_heard((130.0, 1))), 'cluster 2, heard since it settled, out of reach'
    forming = relay._replace(seen=heard({r: 400 for r in ALL} | {2: 90}))  # not heard since it settled (100)
    assert not is_taut(forming, chain_heard((130.0, 1))), 'cluster 2\'s servers may not be there yet'
    assert not is_taut(relay, NOBODY), 'cut off alone: nothing to say of the chain'
    assert not is_taut(relay._replace(hold=(150.0,)), chain_heard((130.0, 1))), 'a silence it takes for lost states'


def test_a_lagged_vehicle_finds_a_taut_chain_short_only_after_patient_steps() -> None:
    """Behind a multirotor's envelope a chain is taut while its relays fly in: it is found one MAP short after
    PATIENT_STEPS of it (rule 'patient'), not TAUT_STEPS; without the rule, after TAUT_STEPS as on the paper's."""
    assert PATIENT_STEPS > TAUT_STEPS

    def first_found(fp: FlockParams) -> int:
        mem = relay_of_edge_12()
        for step in range(1, 2 * PATIENT_STEPS):
            mem = tally(mem, True, ROLES, fp)
            if dict(mem.short).get(code((1, 2)), 0):
                return step
        raise AssertionError('never found short')

    assert first_found(P) == TAUT_STEPS
    assert first_found(MULTIROTOR) == PATIENT_STEPS
    with switched_off(['patient']):
        assert first_found(MULTIROTOR) == TAUT_STEPS


def test_a_chain_found_taut_is_found_short_and_its_share_grown() -> None:
    """Each TAUT_STEPS of tautness find edge (1, 2) one MAP short, up to its demand; every MAP that hears of it
    grows the edge's share by that many MAPs' worth, and only MAPs that join the chain change role."""
    edge = ROLES.edges.index((1, 2)) + ROW.count
    cap = math.ceil(ROLES.demand[edge])
    mem = relay_of_edge_12()
    found = []
    for _ in range(TAUT_STEPS * (cap + 2)):
        mem = tally(mem, True, ROLES, P)
        found.append(dict(mem.short).get(code((1, 2)), 0))
    assert found[TAUT_STEPS - 2] == 0 and found[TAUT_STEPS - 1] == 1 and found[2 * TAUT_STEPS - 1] == 2
    assert found[-1] == cap, 'never more than the edge\'s demand'
    assert tally(mem, False, ROLES, P) == mem, 'a step with the chain slack counts nothing'
    grown = view(ROLES, (), mem.short)
    demand = sum(ROLES.demand)
    assert math.isclose(grown.share[edge], (ROLES.demand[edge] + cap) / (demand + cap), rel_tol=1e-9)
    assert math.isclose(keys.totals(grown.pieces)[(1, 2)], grown.share[edge], abs_tol=1e-9)
    n = 90
    before = [ROLES.of(key_of(i)) for i in range(n)]
    after = [grown.of(key_of(i)) for i in range(n)]
    joined = [i for i in range(n) if after[i] == edge and before[i] != edge]
    assert len(joined) >= cap, 'the chain gains at least the MAPs it was found short of'
    assert all(after[i] == edge for i in range(n) if before[i] != after[i]), 'only MAPs joining the chain change role'


def test_only_a_settled_relay_in_place_counts_its_chain_taut() -> None:
    """A relay still flying to its edge (from another role, or first out) has no chain yet to judge."""
    here = np.array([150.0, 0.0, P.height])
    loose = chain_heard((124.0, 1), (176.0, 2))
    settled = relay_of_edge_12(seen=heard({r: 400 for r in ALL}))
    i = next(i for i in range(100) if ROLES.of(key_of(i)) == ROW.count + ROLES.edges.index((1, 2)))  # a relay's id
    assert demand_switch(settled, i, 0.0, here, ROW, P, 401, loose).taut == 1
    away = np.array([150.0, 2 * P.d, P.height])  # farther than d from the edge: not yet in place
    for moving in (settled._replace(transit=True), settled._replace(settled=False)):
        assert demand_switch(moving, i, 0.0, away, ROW, P, 401, loose).taut == 0


def relays_at(*xs: float) -> Near:
    """Relays of edge (1, 2) heard at these x along it."""
    return Near(np.array([[x, 0.0, P.height] for x in xs]), [Told(M1, 1, (1, 2)) for _ in xs])


def test_a_relay_that_vanishes_from_well_within_range_finds_its_chain_short_at_once() -> None:
    """Rule 'patient', a relay seen to fail: one heard 10 m off at one step and nowhere near there at the next has
    failed, so its chain is one MAP short at once, not after PATIENT_STEPS of tautness. One that moved a step's
    flight, or one heard at the edge of range (it may have flown out of it), is not counted; nor does the paper's
    vehicle, a lossy channel, or the rule switched off count any."""
    me = np.array([150.0, 0.0, P.height])
    first = vanished(relay_of_edge_12(), me, relays_at(140.0, 160.0, 150.0 + P.r - 1.0), MULTIROTOR)
    assert len(first.around) == 2, 'the two relays well within r, not the one at r - 1 m'
    assert first.short == ()
    moved = vanished(first, me, relays_at(141.4, 160.0), MULTIROTOR)
    assert moved.short == (), 'a relay a step\'s flight from where it was is heard again; one at r - 1 m may have left'
    failed = vanished(first, me, relays_at(160.0), MULTIROTOR)
    assert dict(failed.short) == {code((1, 2)): 1}
    both = vanished(first, me, relays_at(), MULTIROTOR)
    assert dict(both.short) == {code((1, 2)): 2}, 'each relay seen to fail counts'
    lossy = dataclasses.replace(MULTIROTOR, hush=10)
    for fp in (P, lossy):
        assert vanished(vanished(relay_of_edge_12(), me, relays_at(140.0), fp), me, relays_at(), fp).short == ()
    with switched_off(['patient']):
        assert vanished(vanished(relay_of_edge_12(), me, relays_at(140.0), MULTIROTOR), me, relays_at(),
                       MULTIROTOR).short == ()


def test_two_maps_that_saw_one_failure_ask_for_one_map() -> None:
    """Both neighbours of a failed relay count it; the gossip keeps the larger count, so the chain asks for one."""
    seen = [vanished(vanished(relay_of_edge_12(), np.array([x, 0.0, P.height]), relays_at(150.0), MULTIROTOR),
                    np.array([x, 0.0, P.height]), relays_at(), MULTIROTOR) for x in (135.0, 165.0)]
    merged = gossip(seen[0], NOW, [], [], [seen[1].short])
    assert dict(merged.short) == {code((1, 2)): 1}


def test_on_a_multirotor_a_short_edge_is_lent_its_maps_by_its_own_clusters() -> None:
    """Rule 'nearest': edge (1, 2) found two MAPs short grows by as much as before, but its two clusters lend it:
    cluster 0, two hops off, keeps its share, and every MAP that joins the chain was a server of cluster 1 or 2."""
    short = ((code((1, 2)), 2),)
    edge = ROW.count + ROLES.edges.index((1, 2))
    alike, lent = view(ROLES, (), short), view(ROLES, (), short, near=True)
    assert math.isclose(lent.share[edge], alike.share[edge], rel_tol=1e-12), 'the same growth'
    assert math.isclose(sum(lent.share), 1.0, rel_tol=1e-12)
    assert lent.share[0] == ROLES.share[0] and alike.share[0] < ROLES.share[0]
    n = 200
    before = [ROLES.of(key_of(i)) for i in range(n)]
    joined = [before[i] for i in range(n) if lent.of(key_of(i)) == edge and before[i] != edge]
    assert len(joined) >= 1 and set(joined) <= {1, 2}, joined
    assert all(lent.of(key_of(i)) in (before[i], edge) for i in range(n)), 'only MAPs joining the chain move'
