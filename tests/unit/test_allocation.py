"""The demand allocation: roles by key, relays by gap, stalled clusters, chains, and one random layout end to end."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uav_agent.core.agent import Neighbourhood, agent_step
from uav_agent.core.clusters import ClusterMap, key_of, mst_edges
from uav_agent.core.allocations.demand import layout
from uav_agent.core.allocations.demand.allocation import STALL_STEPS, relay_place
from uav_agent.core.allocations.demand.memory import Gossip, Mine
from uav_agent.core import policies, state
from uav_agent.core.policies import decide
from uav_agent.core.state import M0, M1, M2, Memory, Told
from uav_agent.core.params import FlockParams
from uav_flock_tools.batch import BatchSimulator
from world_sim.core import layouts, outcome
from world_sim.core.scenario import load

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


def server_of(clusters: ClusterMap, cluster: int) -> int:
    roles = layout.roles(clusters, P.d)
    return next(i for i in range(1000) if roles.of(key_of(i)) == cluster)


def test_a_cluster_stalled_below_r0_still_counts_as_served() -> None:
    clusters = line([100.0, 200.0])
    i = server_of(clusters, 1)
    cover = np.array([0.0, 0.90, 0.0])  # under r0 = 0.95 for good
    mem = Memory()
    here = np.array([clusters.xy[1][0], 0.0, 20.0])
    for _ in range(STALL_STEPS + 2):
        mem = decide(mem, i, 12, cover, here, [], clusters, P)
    assert mem.achieved >> 1 & 1, 'the stalled cluster joins the achieved set'
    assert mem.mode == M2
    growing = Memory()
    for k in range(STALL_STEPS + 2):
        growing = decide(growing, i, 12, np.array([0.0, 0.011 * k, 0.0]), here, [], clusters, P)
    assert not growing.achieved >> 1 & 1 and growing.mode == M0, 'a cluster still gaining is not yet served'


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


class Nearest:
    """The allocation of docs/design.md's example: serve the nearest cluster, attract only its other servers."""

    def decide(self, mem: Memory, agent_id: int, n_users: int, r_g: float, q: np.ndarray, clusters: ClusterMap,
               fp: FlockParams, step: int, near: 'state.Near') -> Memory:
        from uav_agent.core.clusters import NO_GOAL
        goal = clusters.nearest(q, 0)
        return mem._replace(goal=goal, mode=M2 if goal != NO_GOAL and r_g > fp.r0 else M0)

    def reference(self, mem: Memory, agent_id: int, q: np.ndarray, nbr_q: np.ndarray, told: list[Told],
                  clusters: ClusterMap, fp: FlockParams) -> 'state.Reference':
        return state.hold(mem, *state.aim(mem, q, clusters))

    def link(self, a: Told, b: Told) -> int:
        return state.RELATED if a.goal == b.goal else state.APART


def test_a_new_allocation_is_a_class_and_one_registry_line(paper_scenario_path: str,
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(policies.ALLOCATIONS, 'nearest', Nearest())
    s = load(paper_scenario_path).with_overrides(maps=30, duration=20.0)
    s = replace(s, flock=replace(s.flock, allocation='nearest'))
    sim = BatchSimulator(s)
    result = sim.run()
    assert set(result.trajectory[:, 9].astype(int).tolist()) <= {M0, M2}, 'it never bridges'
    assert all(m.goal == sim.clusters.nearest(q, 0) for m, q in zip(sim.memory, sim.q)), \
        'every MAP ends serving its nearest cluster'


def test_the_95_percent_radius_constant_is_scipys_quantile_to_the_last_bit() -> None:
    from scipy.stats import chi2

    from world_sim.core.layouts import CHI2_2DOF_95
    assert CHI2_2DOF_95 == chi2.ppf(0.95, 2)
