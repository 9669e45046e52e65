"""The demand allocation: roles by key, relays by gap, stalled clusters, chains, and one random layout end to end."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uav_agent.core.agent import Neighbourhood, agent_step
from uav_agent.core.allocations.algorithm2 import mode_switch
from uav_agent.core.allocations.demand import layout
from uav_agent.core.allocations.demand.allocation import demand_switch, en_route
from uav_agent.core.allocations.demand.chain import Chain, Ends, anchored, chain_of, hushed, pivot, relay_place, swing_place
from uav_agent.core.allocations.demand.memory import Gossip, Mine
from uav_agent.core.clusters import NO_GOAL, ClusterMap, key_of, mst_edges
from uav_agent.core.params import FlockParams
from uav_agent.core.policies import decide, reference
from uav_agent.core.state import ALONE, M0, M1, M2, NOBODY, SHARED, UNKEPT, Memory, Near, Told
from uav_flock_tools.batch import BatchSimulator
from world_sim.core import layouts, outcome
from world_sim.core.scenario import load
from helpers.roles import role_ids

P = FlockParams()  # the default policies: allocation 'demand'
R = 30.0  # every cluster's 95 % radius in the hand-made layouts


def role_counts(clusters: ClusterMap, n: int) -> np.ndarray:
    roles = layout.roles(clusters, P.d)
    return np.bincount([roles.of(key_of(i)) for i in range(n)], minlength=len(roles.demand))


def line(gaps: list[float]) -> ClusterMap:
    """Clusters on the x axis whose relay gaps (between their outermost servers) are the given lengths."""
    rim = R - P.d / 2
    x = np.cumsum([0.0] + [g + 2 * rim for g in gaps])
    return ClusterMap(np.column_stack([x, np.zeros(len(x))]), P.height, np.full(len(x), R))


def test_the_default_policies_are_the_demand_allocation() -> None:
    assert P.allocation == 'demand'


def test_relays_go_to_edges_in_proportion_to_their_gaps() -> None:
    clusters = line([100.0, 200.0])
    roles = layout.roles(clusters, P.d)
    assert roles.edges == ((0, 1), (1, 2))
    assert math.isclose(roles.demand[3], 100.0 / P.d) and math.isclose(roles.demand[4], 200.0 / P.d)
    counts = role_counts(clusters, 120)
    assert abs(counts[4] - 2 * counts[3]) <= 2, counts  # keys are evenly spread: off by rounding only
    assert max(counts[:3]) - min(counts[:3]) <= 2, 'equal clusters, equal shares'


def test_every_map_of_an_edge_role_bridges_that_edge_in_connectivity_mode() -> None:
    clusters = line([100.0, 200.0])
    roles = layout.roles(clusters, P.d)
    for i in range(40):
        mem = decide(Memory(), i, 0, np.zeros(3), np.array([0.0, 0.0, 20.0]), [], clusters, P)
        role = roles.of(key_of(i))
        if role >= clusters.count:
            assert mem.mode == M1 and mem.bridge == roles.edges[role - clusters.count]
        else:
            assert mem.mode == M0 and mem.goal == role and mem.bridge is None


def test_a_relay_aims_midway_between_the_chain_members_it_hears() -> None:
    clusters = line([100.0, 200.0])
    edge = (0, 1)
    q = np.array([80.0, 3.0, 20.0])
    servers_of_0 = Told(M2, 0, None)
    relay = Told(M1, 0, edge)
    other_edge = Told(M1, 1, (1, 2))
    heard = np.array([[40.0, 0.0, 20.0], [120.0, 0.0, 20.0], [90.0, 0.0, 20.0]])
    assert relay_place(5, q, edge, heard[:2], [servers_of_0, relay], clusters, P) == 80.0
    # a relay of another edge is not part of this chain; with the b side silent, reach as far beyond the a side
    # as the radio carries (r less 1 m): a chain short of relays then still spans r - 1 per link, not d
    reach = P.r - 1.0
    assert relay_place(5, q, edge, heard[[0, 2]], [servers_of_0, other_edge], clusters, P) == 40.0 + reach
    # a server still on its way to its cluster (here out along the edge) is no anchor: the relay takes its
    # own place by its key, as if it heard no one, rather than bend the chain towards it
    alone = relay_place(5, q, edge, heard[:0], [], clusters, P)
    assert relay_place(5, q, edge, heard[[1]], [servers_of_0], clusters, P) == alone != 120.0 + reach
    # so is a relay of this edge still flying in, farther than d from the edge
    assert relay_place(5, q, edge, np.array([[40.0, 0.0, 20.0], [100.0, 2 * P.d, 20.0]]), [servers_of_0, relay],
                       clusters, P) == 40.0 + reach
    # rule 'stay': a settled relay under a lossy channel that hears no one stays where it is along its edge
    assert alone != 80.0 and relay_place(5, q, edge, heard[:0], [], clusters, P, stay=True) == 80.0
    # rule 'offset': the last server heard 15 m off the edge's line: r - 1 m in the plane, less along the edge
    aside = np.array([[30.0, 15.0, 20.0]])
    place = relay_place(5, q, edge, aside, [servers_of_0], clusters, P)
    assert place == pytest.approx(30.0 + math.sqrt(reach ** 2 - 15.0 ** 2))
    assert math.hypot(place - 30.0, 15.0) == pytest.approx(reach)
    lossy = replace(P, hush=30)
    assert relay_place(5, q, edge, aside, [servers_of_0], clusters, lossy) == 30.0 + reach, 'along the line'


def test_a_relay_in_transit_to_a_chain_it_hears_no_member_of_joins_it_at_the_nearer_end_of_its_gap() -> None:
    """Rule 'ends', on a lagged vehicle: by its key a relay on its way to a new chain was sent into the middle of an
    empty gap, alone; hearing no member, it joins at the end of the gap nearer to it, among the anchor's servers, and
    the chain grows from there. A relay that is not in transit, the paper's vehicle, and the rule off: by its key."""
    from uav_agent.core.ablation import switched_off
    lagged = replace(P, v_max=15.0, a_max=4.0, tau=0.3, keep=6.1)
    clusters, edge = line([160.0]), (0, 1)
    start, stop = clusters.gap(edge, P.d / 2)
    nobody = np.zeros((0, 3))
    near_0, near_1 = np.array([start + 50.0, 30.0, 20.0]), np.array([stop - 50.0, -30.0, 20.0])
    i = next(i for i, role in enumerate(role_ids(clusters, 200, P))  # a relay of the edge that its key puts inside
             if role == edge and start + 1.0 < relay_place(i, near_0, edge, nobody, [], clusters, lagged) < stop - 1.0)
    by_key = relay_place(i, near_0, edge, nobody, [], clusters, lagged)
    assert relay_place(i, near_0, edge, nobody, [], clusters, lagged, transit=True) == start
    assert relay_place(i, near_1, edge, nobody, [], clusters, lagged, transit=True) == stop
    assert relay_place(i, near_1, edge, nobody, [], clusters, lagged) == by_key, 'not in transit: by its key'
    assert relay_place(i, near_0, edge, nobody, [], clusters, P, transit=True) == by_key, "the paper's vehicle"
    with switched_off(['ends']):
        assert relay_place(i, near_0, edge, nobody, [], clusters, lagged, transit=True) == by_key
    # a member heard: the chain is there, and the relay reaches past it as any relay does
    server = np.array([[start, 0.0, 20.0]])
    assert relay_place(i, near_0, edge, server, [Told(M2, 0, None)], clusters, lagged, transit=True) > start + 10.0


def test_a_map_in_transit_neither_attracts_a_relay_nor_drags_it_along() -> None:
    """A relay that matched the velocity of a MAP flying past at 40 m/s would leave its chain (the chain of a
    drifting cluster came apart so): a neighbour in transit only repels, and beyond d not even that."""
    clusters = line([100.0])
    edge = (0, 1)
    relay = Mine(mode=M1, goal=0, bridge=edge, settled=True, since=0).memory()
    q = np.array([clusters.axis(edge)[2] / 2, 0.0, P.height])
    past = np.array([[q[0], P.d + 2.0, P.height]])  # between d and r: in range, not too close
    fast = np.array([[40.0, 0.0, 0.0]])

    def u(told: list[Told]) -> np.ndarray:
        hood = Neighbourhood(past[:len(told)], fast[:len(told)], np.zeros(len(told)), [0] * len(told), told)
        return agent_step(relay, 3, q, np.zeros(3), 0, np.zeros(2), hood, clusters, P, 1)[0]

    alone = u([])
    assert np.array_equal(u([Told(M0, 1, None, Gossip(transit=True))]), alone), 'a server of the edge in transit is no pull'
    assert u([Told(M0, 1, None)])[0] > alone[0] + 1.0, 'a settled server of the edge at that speed would drag it'


def test_a_map_in_transit_passes_others_at_half_d_where_unrelated_settled_maps_keep_d() -> None:
    """Kept d away by the servers on a cluster's rim, a MAP on its way to a new role slid round the disc and
    left it off the relay chain: between d/2 and d of a MAP it passes it feels no push either way, while two
    settled MAPs of unrelated roles at that distance still push apart; closer than d/2 both repel."""
    clusters = line([100.0])
    server_of_1 = Mine(mode=M2, goal=1, settled=True, since=0).memory()
    q = np.array([0.0, 0.0, P.height])
    still = np.zeros((1, 3))

    def u(mem: Memory, gap: float, told: Told) -> np.ndarray:
        hood = Neighbourhood(np.array([[gap, 0.0, P.height]]), still, np.zeros(1), [0], [told])
        return agent_step(mem, 1, q, np.zeros(3), 0, np.zeros(2), hood, clusters, P, 1)[0]

    def alone(mem: Memory) -> np.ndarray:
        return agent_step(mem, 1, q, np.zeros(3), 0, np.zeros(2), Neighbourhood.empty(), clusters, P, 1)[0]

    passing = Told(M0, 0, None, Gossip(transit=True))   # on its way through cluster 1 to cluster 0
    settled = Told(M0, 0, None)                 # a server of cluster 0, unrelated to one of cluster 1
    gap = 0.75 * P.d
    assert np.array_equal(u(server_of_1, gap, passing), alone(server_of_1)), 'no push from one passing at 3d/4'
    assert u(server_of_1, gap, settled)[0] < alone(server_of_1)[0] - 1.0, 'an unrelated settled MAP repels'
    assert u(server_of_1, 0.3 * P.d, passing)[0] < alone(server_of_1)[0] - 1.0, 'closer than d/2 it repels'


def test_under_the_safety_filter_a_map_in_transit_is_kept_d_away_as_a_settled_one_is() -> None:
    """Passing at d/2 let a MAP in transit close on unrelated ones until the filter's separation rows turned it
    aside late and hard, and an arrival recovered later under the filter (docs/vehicle.md, "The filter without
    rule passing"): under the filter eq. 10's repulsion keeps every unrelated pair d apart; under the rules, as
    before, d/2."""
    from uav_agent.core.policies import ALLOCATIONS
    from uav_agent.core.state import APART, PASSING
    rules = replace(P, v_max=15.0, a_max=4.0, tau=0.3, keep=6.1)
    filtered = replace(rules, safety='filter')
    demand = ALLOCATIONS['demand']
    passing, server = Told(M0, 0, None, Gossip(transit=True)), Told(M2, 1, None)
    assert demand.link(passing, server, rules) == PASSING and demand.link(server, passing, rules) == PASSING
    assert demand.link(passing, server, filtered) == APART and demand.link(server, passing, filtered) == APART
    assert demand.link(passing, server, replace(P, safety='filter')) == PASSING, 'no filter flies the paper\'s vehicle'


def test_a_relay_that_knows_its_rank_and_both_anchors_flies_to_its_share_of_the_span() -> None:
    """Rule 'ends': each relay passes on its count of links to either anchor and where that anchor is, one hop more
    than the member it hears on that side says; knowing both, a relay aims at its even share of the span at once.
    A chain too short for its span, or one that knows one anchor only, is laid out taut from it; under the paper's
    vehicle, or without the rule, the relay aims midway between the members it hears."""
    from uav_agent.core.ablation import switched_off
    lagged = replace(P, v_max=15.0, a_max=4.0, tau=0.3, keep=6.1)
    clusters, edge = line([100.0]), (0, 1)
    link = P.r - 1.0
    q = np.array([80.0, 0.0, 20.0])
    heard = np.array([[60.0, 0.0, 20.0], [100.0, 0.0, 20.0]])

    def relays(below: tuple[float, ...], above: tuple[float, ...]) -> list[Told]:
        return [Told(M1, 0, edge, Gossip(ends=below)), Told(M1, 0, edge, Gossip(ends=above))]

    told = relays((3.0, 10.0, 0.0, 0.0), (0.0, 0.0, 2.0, 130.0))
    assert chain_of(q, edge, heard, told, clusters, lagged).ends == Ends(4, 10.0, 3, 130.0)
    assert relay_place(5, q, edge, heard, told, clusters, lagged) == pytest.approx(10.0 + 4 / 7 * 120.0)
    assert relay_place(5, q, edge, heard, told, clusters, P) == 80.0, "the paper's vehicle: midway"
    with switched_off(['ends']):
        assert chain_of(q, edge, heard, told, clusters, lagged).ends == Ends()
        assert relay_place(5, q, edge, heard, told, clusters, lagged) == 80.0
    too_long = relays((3.0, 10.0, 0.0, 0.0), (0.0, 0.0, 2.0, 200.0))  # 190 m for 7 links of r - 1 m
    assert relay_place(5, q, edge, heard, too_long, clusters, lagged) == pytest.approx(10.0 + 4 * link)
    one_end = relays((3.0, 10.0, 0.0, 0.0), ())
    assert relay_place(5, q, edge, heard, one_end, clusters, lagged) == pytest.approx(10.0 + 4 * link)
    stale = relays((64.0, 10.0, 0.0, 0.0), (0.0, 0.0, 2.0, 130.0))  # a count past ENDS_HOPS: a loop, not a chain
    assert chain_of(q, edge, heard, stale, clusters, lagged).ends == Ends(0, 0.0, 3, 130.0)
    # the server heard below is the anchor itself, one link off, as a point on the line
    rim = np.array([[35.0, 0.0, 20.0], heard[1]])  # within cluster 0's disc
    server = chain_of(q, edge, rim, [Told(M2, 0, None), told[1]], clusters, lagged).ends
    assert server[0] == 1 and server[1] == pytest.approx(35.0) and server[2:] == (3, 130.0)


def test_on_a_lagged_vehicle_a_relay_and_its_servers_only_repel() -> None:
    """Rule 'loose': behind a lag the servers' pull held relays inside their cluster and the chain never spanned
    its gap; on the paper's vehicle they attract as before, and fellow relays always do."""
    from uav_agent.core.ablation import switched_off
    from uav_agent.core.policies import ALLOCATIONS
    from uav_agent.core.state import APART, INLINE, RELATED
    lagged = replace(P, v_max=15.0, a_max=4.0, tau=0.3, keep=6.1)
    demand = ALLOCATIONS['demand']
    relay, fellow, server = Told(M1, 0, (0, 1)), Told(M1, 0, (0, 1)), Told(M2, 1, None)
    assert demand.link(relay, server, P) == RELATED and demand.link(server, relay, P) == RELATED
    assert demand.link(relay, server, lagged) == APART and demand.link(server, relay, lagged) == APART
    assert demand.link(relay, fellow, P) == RELATED and demand.link(relay, fellow, lagged) == INLINE
    with switched_off(['loose', 'inline']):
        assert demand.link(relay, server, lagged) == RELATED and demand.link(relay, fellow, lagged) == RELATED


def test_the_links_the_filter_keeps_are_a_chains_between_maps_settled_at_their_roles_once_its_clusters_are_served() -> None:
    """Allocation.needed (rule 'links'): fellow relays of one edge, both keeping it, and a relay with a server of its
    edge's clusters, the relay alone keeping it, both settled, once both the chain's clusters are among the own MAP's
    achieved goals; never two servers of one cluster, a MAP not yet at its role, one in transit, another chain's, or a
    chain to a cluster not yet served."""
    from uav_agent.core.policies import ALLOCATIONS
    demand = ALLOCATIONS['demand']
    at = Gossip(settled=True)
    served = 0b111  # clusters 0, 1 and 2 achieved

    def own(told: Told, achieved: int = served) -> Memory:
        mine = Mine.of(Memory(mode=told.mode, goal=told.goal, bridge=told.bridge, achieved=achieved))
        return mine._replace(settled=True).memory()

    relay, fellow, server = Told(M1, 0, (0, 1), at), Told(M1, 0, (0, 1), at), Told(M2, 1, None, at)
    assert demand.needed(own(relay), fellow) == SHARED
    assert demand.needed(own(relay), server) == ALONE and demand.needed(own(server), relay) == UNKEPT, 'the relay follows'
    assert not demand.needed(own(server), Told(M2, 1, None, at)), "a cluster's lattice"
    assert not demand.needed(own(relay), Told(M1, 0, (0, 1), Gossip())), 'a relay still on its way to the chain'
    assert not demand.needed(own(relay), Told(M2, 1, None, Gossip(transit=True, settled=True))), 'a server in transit'
    assert not demand.needed(own(relay), Told(M1, 1, (1, 2), at)) and not demand.needed(own(relay), Told(M2, 2, None, at))
    for achieved in (0b001, 0b010, 0):  # the chain's second or first cluster, or neither, not yet served
        assert not demand.needed(own(relay, achieved), fellow), 'a chain to a cluster not yet served'
        assert not demand.needed(own(server, achieved), relay) and not demand.needed(own(relay, achieved), server)
    assert not ALLOCATIONS['algorithm2'].needed(own(relay), fellow)


def test_fellow_relays_on_a_lagged_vehicle_space_themselves_along_their_edge_only() -> None:
    """Rule 'inline': two fellow relays side by side across their edge's line (closer than d across it, level
    along it) push each other neither aside nor along; one closer than d along the edge is pushed along it, and
    by the same amount whatever its offset across the line."""
    from uav_agent.core.control import flocking_terms
    from uav_agent.core.state import INLINE, RELATED
    axis = np.array([[1.0, 0.0, 0.0]])
    own = np.array([[0.0, 0.0, P.height]])

    def f(offset: list[float], link: int) -> np.ndarray:
        nbr = own + np.array([offset])
        return flocking_terms(own, np.zeros((1, 3)), np.zeros(1), np.array([0]), nbr, np.zeros((1, 3)), np.zeros(1),
                              P, np.array([link]), axis)[0]

    across = f([0.0, 0.5 * P.d, 0.0], INLINE)
    assert np.allclose(across, 0.0), across
    assert f([0.0, 0.5 * P.d, 0.0], RELATED)[1] < -1.0, 'in the plane the lattice pushes it aside'
    near, off_line = f([0.5 * P.d, 0.0, 0.0], INLINE), f([0.5 * P.d, 0.4 * P.d, 0.0], INLINE)
    assert near[0] < -1.0 and abs(near[1]) < 1e-12, near
    assert np.allclose(near, off_line), (near, off_line)


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 7), st.integers(0, 2**32 - 1), st.floats(0.3, 3.0))
def test_every_role_gets_its_share_of_any_id_range(k: int, seed: int, scale: float) -> None:
    """Golden-ratio keys of ids 0..N-1 fill each share within rounding: never more than 2.5 MAPs off."""
    rng = np.random.default_rng(seed)
    clusters = ClusterMap(rng.uniform(0, 400, size=(k, 2)), P.height, rng.uniform(20, 45, size=k))
    roles = layout.roles(clusters, P.d)
    n = max(1, math.ceil(scale * sum(roles.demand)))
    counts = role_counts(clusters, n)
    shares = n * np.array(roles.share)
    assert np.all(np.abs(counts - shares) <= 2.5), (counts, shares)


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 7), st.integers(0, 2**32 - 1))
def test_with_maps_for_every_demand_no_edge_is_left_without_its_relays(k: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 400, size=(k, 2))
    clusters = ClusterMap(xy, P.height, rng.uniform(20, 45, size=k))
    roles = layout.roles(clusters, P.d)
    n = math.ceil(1.25 * sum(roles.demand)) + 2 * len(roles.demand)  # every demand, a quarter more, and slack
    counts = role_counts(clusters, n)
    for j, edge in enumerate(roles.edges):
        demand = roles.demand[k + j]
        assert counts[k + j] >= (1 if demand >= 1 else 0), f'edge {edge}: no relay for a demand of {demand:.2f}'
        assert counts[k + j] >= math.floor(demand) - 1, f'edge {edge}: {counts[k + j]} relays for {demand:.2f}'
    assert sorted(roles.edges) == [tuple(e) for e in mst_edges(xy)], 'the tree spans every cluster from the start'


@pytest.mark.slow
def test_a_small_random_layout_ends_covered_and_connected(paper_scenario_path: str) -> None:
    paper = load(paper_scenario_path)
    lay = layouts.draw(paper, layouts.LayoutSpec(clusters=(3, 3)), np.random.default_rng(11))
    floor = layouts.floor(lay)
    s = replace(lay, maps=2 * floor.total, duration=60.0, flock=replace(paper.flock, allocation='demand'))
    result = BatchSimulator(s).run()
    o = outcome.judge(s, result.metrics, result.trajectory)
    assert o.success, o
    assert all(n >= f for n, f in zip(o.per_cluster, floor.per_cluster)), (o.per_cluster, floor.per_cluster)


def test_without_the_clusters_extent_every_map_serves_a_cluster() -> None:
    """A /clusters message without radii (by hand, or an old recording): equal shares, nobody relays blind."""
    clusters = ClusterMap(np.array([[0.0, 0.0], [150.0, 0.0], [300.0, 0.0]]), P.height)
    counts = role_counts(clusters, 30)
    assert counts[3:].sum() == 0 and max(counts[:3]) - min(counts[:3]) <= 2, counts


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


def test_on_a_lagged_vehicle_a_swapped_edge_stands_and_its_relays_let_go_join_the_nearer_cluster() -> None:
    """The case above on a lagged vehicle: a swing there is break before make (until the chain's far end reaches
    cluster 0, cluster 2's side is cut off), so the swapped edge (1, 2) stands for STANDING surveys, its relays kept,
    while (0, 2) is staffed from the clusters. Let go, a relay joins the nearer of 1 and 2 by where it is, not the one
    its key names, and stays with it; the paper's vehicle swings as before."""
    from uav_agent.core.ablation import switched_off
    fp, n = FlockParams(), 150
    lagged = replace(fp, v_max=15.0, a_max=4.0, tau=0.3, keep=6.1)
    radii = np.full(3, 25.0)
    xy = np.array([[0.0, 0.0], [150.0, 0.0], [200.0, 120.0]])
    moved = np.array([[0.0, 0.0], [150.0, 0.0], [60.0, 140.0]])
    ideal = ClusterMap(moved, fp.height, radii, previous=ClusterMap(xy, fp.height, radii))
    assert layout.roles(ideal, fp.d).standing == (), "the paper's vehicle: the chain swings"
    maps = [ClusterMap(xy, fp.height, radii)]
    for _ in range(layout.STANDING + 1):
        maps.append(ClusterMap(moved, fp.height, radii, previous=maps[-1]))
        layout.roles(maps[-1], fp.d, near=True)  # laid out before the next survey drops the one it carries from
    assert layout.roles(maps[1], fp.d, near=True).edges == ((0, 1), (0, 2), (1, 2))
    assert layout.roles(maps[1], fp.d, near=True).standing == (((1, 2), layout.STANDING),)
    was, kept = role_ids(maps[0], n, fp, near=True), role_ids(maps[1], n, fp, near=True)
    relays = [i for i in range(n) if was[i] == (1, 2) and kept[i] == (1, 2)]
    assert len(relays) >= 0.9 * was.count((1, 2)) >= 4, 'the chain keeps its relays (its share as its length says)'
    a, b = moved[1], moved[2]
    for m in maps[1:-1]:
        for i, f in zip(relays, np.linspace(0.2, 0.8, len(relays))):
            q = np.array([*(a + f * (b - a)), fp.height])
            mem = demand_switch(Mine(mode=M1, goal=1, bridge=(1, 2), settled=True), i, 0.0, q, m, lagged)
            assert mem.mode == M1 and mem.bridge == (1, 2) and mem.swing is None, 'the chain stands, no relay swings'
    last = maps[-1]
    assert layout.roles(last, fp.d, near=True).edges == ((0, 1), (0, 2)), 'then it is let go'
    named = role_ids(last, n, fp, near=True)
    assert {named[i] for i in relays} == {1, 2}, 'its keys name both its clusters'
    for i in relays:
        for f, nearer in ((0.25, 1), (0.75, 2)):
            q = np.array([*(a + f * (b - a)), fp.height])
            mem = demand_switch(Mine(mode=M1, goal=1, bridge=(1, 2), settled=True), i, 0.0, q, last, lagged)
            assert (mem.mode, mem.goal, mem.rejoin) == (M0, nearer, (named[i], nearer)), \
                f'relay {i} a quarter of the way from cluster {nearer} joins it, its key naming {named[i]}'
            on = demand_switch(mem, i, 0.0, np.array([*moved[nearer], fp.height]), last, lagged)
            assert on.goal == nearer, 'and stays with it once there'
    with switched_off(['nearest']):
        assert layout.roles(last, fp.d).standing == () and demand_switch(
            Mine(mode=M0, goal=2, settled=True, rejoin=(2, 1)), relays[0], 0.0, np.array([*a, fp.height]), last,
            lagged).rejoin is None, "without rule 'nearest' a MAP goes where its key says"


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


def test_on_a_lagged_vehicle_a_relay_one_standing_chain_gives_up_to_another_flies_the_tree_not_the_chord() -> None:
    """Rule 'swing' swings a swapped edge's relays; a relay that chain (0, 1), still in the tree, gives up to (0, 2)
    swings alone. On a lagged vehicle it flew the chord out of everyone's range, so it flies the tree instead (along
    (0, 1) to cluster 0, then out along (0, 2)); on the paper's vehicle, where a chord takes a step or two, it swings."""
    clusters = ClusterMap(np.array([[0.0, 0.0], [150.0, 0.0], [60.0, 140.0], [300.0, 50.0]]), P.height,
                          np.full(4, 25.0))
    lagged = replace(P, v_max=15.0, a_max=4.0, tau=0.3, keep=6.1)
    q = np.array([120.0, 0.0, P.height])
    settled = Mine(mode=M1, goal=0, bridge=(0, 1), settled=True)
    both = ((0, 1), (0, 2))
    assert pivot(settled, q, (0, 2), clusters, lagged) == (0, pytest.approx(0.875)), "its edge left the tree: a swing"
    assert pivot(settled, q, (0, 2), clusters, P, both) == (0, pytest.approx(0.875)), "the paper's vehicle swings"
    assert pivot(settled, q, (0, 2), clusters, lagged, both) is None
    moved = Mine(mode=M1, goal=0, bridge=(0, 2), settled=True, transit=True)
    assert en_route(moved, q, clusters, lagged) == 0, 'in transit along the tree: first to cluster 0'


def test_under_a_lossy_channel_a_map_holds_its_place_through_a_silence_no_longer_than_the_channels_losses_last() -> None:
    """Rule 'hold': a relay that heard its chain on both sides, or a server that heard a relay of its cluster,
    within fp.hush steps keeps the place it had when the silence began; past hush it acts as before."""
    lossy = replace(P, hush=30)
    relay = Mine(mode=M1, goal=0, bridge=(0, 1), settled=True, since=100)
    both, one_side = Chain(150.0, 130.0, 170.0), Chain(152.0, 130.0, math.inf)
    heard = hushed(relay, both, 200, lossy)
    assert (heard.whole, heard.hold) == (200, None)
    silent = hushed(heard, one_side, 210, lossy)
    assert silent.hold == (152.0,), 'where it was when the side fell silent'
    assert hushed(silent, one_side._replace(here=155.0), 230, lossy).hold == (152.0,), 'and there it stays'
    assert hushed(silent, one_side, 231, lossy).hold is None, 'silent past hush: an empty side, reached for'
    assert hushed(heard, both, 231, lossy).hold is None
    assert hushed(relay, one_side, 210, P) == relay, 'the paper\'s channel: silence is absence'
    two = line([100.0])
    server = Mine(mode=M2, goal=1, settled=True, since=100)
    relay_near = Near(np.array([[two.xy[1, 0] - 40.0, 0.0, P.height]]), [Told(M1, 0, (0, 1))])
    at = np.array([two.xy[1, 0] - 22.0, 3.0, P.height])
    server = anchored(server, at, relay_near, two, 300, lossy)
    assert (server.whole, server.hold) == (300, None)
    held = anchored(server, at, NOBODY, two, 310, lossy)
    assert held.hold == pytest.approx((-22.0, 3.0)), 'its offset from its cluster\'s centre'
    ref = reference(held.memory(), 7, at + [1.0, 0.0, 0.0], np.zeros((0, 3)), [], two, lossy)
    assert ref.target[:2] == pytest.approx(at[:2]), 'its goal term aims where it held, not at the centre'
