"""The safety filter (rule 'filter', uav_agent/core/safety.py): separation and the envelope as constraints on each
MAP's command, flown through the multirotor's own lag (world_sim/core/airframes/multirotor.py)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from uav_agent.core import safety
from uav_agent.core.params import FlockParams
from world_sim.core import vehicle
from world_sim.core.airframes.multirotor import Multirotor

CALM = replace(vehicle.MULTIROTOR, wind=vehicle.Wind(0.0, 0.0, 0.0, 5.0), gnss=vehicle.Gnss(0.0, 60.0, 0.0))
FP = replace(FlockParams(), **CALM.envelope())


def pairs(q: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every ordered pair (i, j) as the filter takes it: owner i, j's position and velocity less i's."""
    n = len(q)
    i, j = np.array([(a, b) for a in range(n) for b in range(n) if a != b]).T
    return i, q[j] - q[i], p[j] - p[i]


def fly(q: np.ndarray, p: np.ndarray, nominal: np.ndarray, seconds: float, v: vehicle.Vehicle = CALM,
        filter_on: bool = True) -> float:
    """The MAPs flown from q, p, each commanding the filtered nominal (a fixed acceleration each) through the
    vehicle's lag and limits: the least distance between two of them."""
    f = Multirotor(v, len(q), 0.1, np.random.default_rng(0))
    rows, least = np.arange(len(q)), np.inf
    for _ in range(int(round(seconds / 0.1))):
        owner, dq, dv = pairs(q, p)
        keep = np.flatnonzero(safety.binding(dq, dv, FP))
        u = safety.filtered(nominal, p, owner[keep], dq[keep], dv[keep], FP).u if filter_on else nominal
        assert (np.linalg.norm(u[:, :2], axis=1) <= FP.a_max + 1e-9).all(), 'a command beyond a_max'
        q, p = f.step(rows, q, p, u)
        gaps = np.linalg.norm(q[:, None] - q[None], axis=2) + np.diag(np.full(len(q), np.inf))
        least = min(least, float(gaps.min()))
    return least


@pytest.mark.parametrize('lateral', [0.0, 2.0])
def test_two_maps_head_on_at_v_max_pushed_together_keep_their_separation(lateral: float) -> None:
    """Both at 15 m/s straight at each other, heard at the traffic receiver's 100 m, each nominal pushing on at
    a_max: the filter brakes them apart of the separation; without it they collide."""
    q = np.array([[0.0, 0.0, 20.0], [100.0, lateral, 20.0]])
    p = np.array([[15.0, 0.0, 0.0], [-15.0, 0.0, 0.0]])
    nominal = np.array([[4.0, 0.0, 0.0], [-4.0, 0.0, 0.0]])
    assert fly(q, p, nominal, 12.0) >= CALM.separation
    assert fly(q, p, nominal, 12.0, filter_on=False) < CALM.separation, 'the case needs no filter'


def test_two_maps_passing_wide_of_each_other_are_not_braked() -> None:
    """On opposite tracks 10 m apart (wider than keep, 4 m calm) at 10 m/s each, seen from 40 m: their line of
    centres closes at 19 m/s, faster than they could stop keep short, but they pass. The collision cone lets them
    fly on; the line-of-centres barrier alone would brake each at more than a_max. Offset 2 m, inside keep, they
    are turned aside rather than braked along their track."""
    p = np.array([[10.0, 0.0, 0.0], [-10.0, 0.0, 0.0]])
    wide = np.array([[0.0, 0.0, 20.0], [40.0, 10.0, 20.0]])
    owner, dq, dv = pairs(wide, p)
    assert (safety.separation(dq, dv, FP)[1] > 0.0).all()
    assert (safety.line_budget(dq, dv, FP) < -FP.a_max).all()
    u = safety.filtered(np.zeros((2, 3)), p, owner, dq, dv, FP).u
    assert np.array_equal(u, np.zeros((2, 3)))
    assert fly(wide, p, np.zeros((2, 3)), 6.0) > 9.0
    close = np.array([[0.0, 0.0, 20.0], [40.0, 2.0, 20.0]])
    owner, dq, dv = pairs(close, p)
    row, bound = safety.separation(dq, dv, FP)
    assert (np.abs(row[:, 1]) > 0.9).all() and (bound < 0.0).all(), (row, bound)
    assert fly(close, p, np.zeros((2, 3)), 6.0) >= CALM.separation


def test_a_crowd_pushed_onto_one_point_keeps_its_separation() -> None:
    """Eight MAPs on a ring of 40 m, every nominal at a_max towards its centre, gusts and GNSS error of the shipped
    profile included in the flight (the filter sees the truth here): none comes within the separation."""
    angles = np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False)
    q = np.column_stack([40.0 * np.cos(angles), 40.0 * np.sin(angles), np.full(8, 20.0)])
    p = np.zeros((8, 3))
    nominal = np.column_stack([-4.0 * np.cos(angles), -4.0 * np.sin(angles), np.zeros(8)])
    windy = replace(vehicle.MULTIROTOR, gnss=vehicle.Gnss(0.0, 60.0, 0.0))
    assert fly(q, p, nominal, 20.0, windy) >= CALM.separation
    assert fly(q, p, nominal, 20.0, windy, filter_on=False) < CALM.separation, 'the case needs no filter'


def test_the_filter_leaves_a_nominal_alone_where_no_barrier_binds() -> None:
    q = np.array([[0.0, 0.0, 20.0], [60.0, 0.0, 20.0]])
    p = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    owner, dq, dv = pairs(q, p)
    assert not safety.binding(dq, dv, FP).any()
    nominal = np.array([[0.5, -1.0, 0.0], [2.0, 1.0, 0.0]])
    assert np.array_equal(safety.filtered(nominal, p, owner[:0], dq[:0], dv[:0], FP).u, nominal)


def test_when_the_envelope_leaves_no_room_separation_is_relaxed_and_the_envelope_kept() -> None:
    """Two MAPs 1 m apart closing at 30 m/s: no command within a_max keeps the barrier. Each brakes away from the
    other with all it has and stays within the polygon inside a_max."""
    q = np.array([[0.0, 0.0, 20.0], [5.0, 0.0, 20.0]])
    p = np.array([[14.0, 0.0, 0.0], [-14.0, 0.0, 0.0]])
    owner, dq, dv = pairs(q, p)
    u = safety.filtered(np.array([[4.0, 0.0, 0.0], [-4.0, 0.0, 0.0]]), p, owner, dq, dv, FP).u
    assert u[0, 0] < -0.9 * FP.a_max and u[1, 0] > 0.9 * FP.a_max, u
    assert (np.linalg.norm(u[:, :2], axis=1) <= FP.a_max + 1e-9).all(), u


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 7), st.integers(0, 2 ** 31 - 1))
def test_each_maps_command_is_the_same_alone_as_in_the_batch(n: int, seed: int) -> None:
    """The node filters its one MAP, the batch simulator all at once: the same bits either way."""
    rng = np.random.default_rng(seed)
    q = np.c_[rng.uniform(0.0, 40.0, (n, 2)), np.full(n, 20.0)]
    p = np.c_[rng.uniform(-15.0, 15.0, (n, 2)) / np.sqrt(2.0), np.zeros(n)]
    nominal = np.c_[rng.normal(0.0, 4.0, (n, 2)), np.zeros(n)]
    owner, dq, dv = pairs(q, p)
    keep = np.flatnonzero(safety.binding(dq, dv, FP))
    owner, dq, dv = owner[keep], dq[keep], dv[keep]
    batch = safety.filtered(nominal, p, owner, dq, dv, FP).u
    assert (np.linalg.norm(batch[:, :2], axis=1) <= FP.a_max + 1e-9).all()
    for i in range(n):
        mine = owner == i
        alone = safety.filtered(nominal[i:i + 1], p[i:i + 1], np.zeros(mine.sum(), dtype=np.intp), dq[mine],
                                dv[mine], FP).u
        assert np.array_equal(alone[0], batch[i]), i


@settings(max_examples=80, deadline=None)
@given(st.integers(2, 40), st.floats(20.0, 120.0), st.integers(0, 2 ** 31 - 1))
def test_the_protected_links_span_every_part_of_the_radio_graph_and_both_ends_agree(n: int, side: float,
                                                                                  seed: int) -> None:
    """Each MAP decides from what it hears alone; over all MAPs the links they protect join whatever the radio
    graph joins (Toussaint's RNG contains the MST), and each is protected by both its ends."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    rng = np.random.default_rng(seed)
    q = np.c_[rng.uniform(0.0, side, (n, 2)), np.full(n, 20.0)]
    gaps = np.linalg.norm(q[:, None] - q[None], axis=2)
    i, j = np.nonzero((gaps < FP.r) & ~np.eye(n, dtype=bool))  # sorted by owner, then neighbour: as heard
    mask = safety.protected(i, q[j] - q[i], n, np.ones(len(i), dtype=bool))
    kept = set(zip(i[mask].tolist(), j[mask].tolist()))
    assert all((b, a) in kept for a, b in kept), 'a link protected by one end only'

    def parts(a: np.ndarray, b: np.ndarray) -> int:
        return connected_components(coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n)), directed=False)[0]
    assert parts(i[mask], j[mask]) == parts(i, j)
    assert mask.sum() <= 2 * 3 * n, 'the relative-neighbourhood graph of points in the plane has under 3n edges'


def test_a_protected_link_holds_against_nominals_pulling_apart_at_a_max() -> None:
    """Two MAPs 20 m apart, each nominal at a_max away from the other, through the vehicle's lag: the link stays
    within r for 20 s; unprotected, it breaks."""
    def widest(links: bool) -> float:
        f = Multirotor(CALM, 2, 0.1, np.random.default_rng(0))
        q, p = np.array([[0.0, 0.0, 20.0], [20.0, 0.0, 20.0]]), np.zeros((2, 3))
        nominal, most = np.array([[-4.0, 0.0, 0.0], [4.0, 0.0, 0.0]]), 0.0
        for _ in range(200):
            owner, dq, dv = pairs(q, p)
            kept = np.flatnonzero(safety.protected(owner, dq, 2, safety.link_budget(dq, dv, FP) < FP.a_max))
            held = (owner[kept], dq[kept], dv[kept], np.zeros(len(kept), bool), np.zeros(len(kept))) if links else None
            u = safety.filtered(nominal, p, owner[:0], dq[:0], dv[:0], FP, held).u
            q, p = f.step(np.arange(2), q, p, u)
            most = max(most, float(np.linalg.norm(q[0] - q[1])))
        return most
    assert widest(True) < FP.r
    assert widest(False) > FP.r


def test_a_link_is_let_go_only_once_a_nearer_map_joins_its_ends() -> None:
    """MAPs 0 and 1 are 22 m apart: alone, their link is protected; with MAP 2 between them, nearer to both, it
    is not (2's links to each are, so the three stay joined)."""
    q = np.array([[0.0, 0.0, 20.0], [22.0, 0.0, 20.0], [11.0, 3.0, 20.0]])
    owner, dq, _ = pairs(q[:2], np.zeros((2, 3)))
    assert safety.protected(owner, dq, 2, np.ones(2, dtype=bool)).all()
    owner, dq, _ = pairs(q, np.zeros((3, 3)))
    mask = safety.protected(owner, dq, 3, np.ones(len(owner), dtype=bool))
    other = np.array([1, 2, 0, 2, 0, 1])  # pairs() lists each owner's others in ascending order
    assert {tuple(sorted(e)) for e in zip(owner[mask].tolist(), other[mask].tolist())} == {(0, 2), (1, 2)}


def test_the_map_that_opens_a_link_takes_its_share_of_holding_it() -> None:
    """A MAP flying away from a relay at rest brakes for their link, the relay is left where the network has it;
    at rest both take half, and the two ends' shares always add up to the whole budget."""
    dq = np.array([[20.0, 0.0, 0.0]])
    still, leaving = np.zeros((1, 3)), np.array([[-8.0, 0.0, 0.0]])  # i flies away from j, along -n
    assert safety.opening_share(dq, still, still)[0] == pytest.approx(0.5)
    mine = safety.opening_share(dq, leaving, still)[0]
    theirs = safety.opening_share(-dq, still, leaving)[0]
    assert mine > 0.9 and mine + theirs == pytest.approx(1.0)


def test_a_relay_that_keeps_its_link_to_a_server_alone_follows_it_and_the_server_flies_free() -> None:
    """A server 16 m from its relay flies away from it at 6 m/s, its nominal to fly on, the relay's to hold still:
    with the link the relay's alone (state.ALONE), the server flies on as its nominal asks and the relay follows, the
    link within r for 10 s; shared, the server is held back; kept by nobody, the link breaks. (The relay does not
    hear the server's acceleration: one that speeds up away from it for long stretches the link past r - 1 m.)"""
    def flown(keeper: str) -> tuple[float, float]:
        f = Multirotor(CALM, 2, 0.1, np.random.default_rng(0))
        q = np.array([[0.0, 0.0, 20.0], [16.0, 0.0, 20.0]])  # the relay, the server
        p, nominal, widest = np.array([[0.0, 0.0, 0.0], [6.0, 0.0, 0.0]]), np.zeros((2, 3)), 0.0
        for _ in range(100):
            owner, dq, dv = pairs(q, p)
            rows = {'alone': [0], 'shared': [0, 1], 'nobody': []}[keeper]
            link = (owner[rows], dq[rows], dv[rows], np.full(len(rows), keeper == 'alone'), np.zeros(len(rows)))
            u = safety.filtered(nominal, p, owner[:0], dq[:0], dv[:0], FP, link).u
            q, p = f.step(np.arange(2), q, p, u)
            widest = max(widest, float(np.linalg.norm(q[0] - q[1])))
        return widest, float(q[1, 0])
    alone, shared, nobody = flown('alone'), flown('shared'), flown('nobody')
    assert alone[0] < FP.r and alone[1] == pytest.approx(nobody[1]), ('the relay follows, the server flies on', alone, nobody)
    assert shared[1] < alone[1] - 20.0, ('shared, the server is held back', shared, alone)
    assert nobody[0] > FP.r

def test_a_link_heard_late_is_kept_shorter_by_how_far_its_ends_could_have_flown_since() -> None:
    """Two MAPs 16 m apart at rest, each pulled away from the other at a_max, keeping their link shared; MAP 0
    hears MAP 1's state once a second and places it where its velocity then takes it (ear.py's rule 'predict').
    Its link's margin grows with the state's age (safety.stale_margin), and the link stays within r - 1 m as when
    heard every step; taking the old state for a fresh one, MAP 0 lets it open past that."""
    def widest(late: bool) -> float:
        f = Multirotor(CALM, 2, 0.1, np.random.default_rng(0))
        q, p = np.array([[0.0, 0.0, 20.0], [16.0, 0.0, 20.0]]), np.zeros((2, 3))
        nominal, flown, most = np.array([[-4.0, 0.0, 0.0], [4.0, 0.0, 0.0]]), [], 0.0
        for k in range(300):
            flown.append((q[1].copy(), p[1].copy()))
            age = k % 10  # steps since MAP 1's last state that MAP 0 heard
            heard_q, heard_p = flown[k - age][0] + age * 0.1 * flown[k - age][1], flown[k - age][1]
            link = (np.array([0, 1]), np.array([heard_q - q[0], q[0] - q[1]]), np.array([heard_p - p[0], p[0] - p[1]]),
                    np.zeros(2, bool), safety.stale_margin(np.array([age * 0.1 if late else 0.0, 0.0]), FP))
            u = safety.filtered(nominal, p, np.zeros(0, np.intp), np.zeros((0, 3)), np.zeros((0, 3)), FP, link).u
            q, p = f.step(np.arange(2), q, p, u)
            most = max(most, float(np.linalg.norm(q[0] - q[1])))
        return most
    reach = FP.r - safety.LINK_MARGIN
    assert safety.stale_margin(np.array([0.0, 0.5]), FP).tolist() == [0.0, FP.a_max * 0.25]
    assert widest(True) < reach + 0.05 < widest(False) - 0.1, (widest(True), widest(False), reach)


def test_the_filter_says_when_a_link_held_a_map_back_and_when_it_gave_way() -> None:
    """Two MAPs 22 m apart at rest, each pulled away at a_max: the link holds both back (HELD, not RELAXED). Flying
    apart at 12 m/s already, no command within a_max keeps the link's barrier: it gives way (RELAXED). A nominal
    that closes the link is neither."""
    q = np.array([[0.0, 0.0, 20.0], [22.0, 0.0, 20.0]])
    apart = np.array([[-4.0, 0.0, 0.0], [4.0, 0.0, 0.0]])
    for p, nominal, want in ((np.zeros((2, 3)), apart, safety.HELD),
                             (np.array([[-6.0, 0.0, 0.0], [6.0, 0.0, 0.0]]), apart, safety.HELD | safety.RELAXED),
                             (np.zeros((2, 3)), -apart, 0)):
        owner, dq, dv = pairs(q, p)
        kept = np.flatnonzero(safety.protected(owner, dq, 2, np.ones(2, dtype=bool)))
        flags = safety.filtered(nominal, p, owner[:0], dq[:0], dv[:0], FP,
                                (owner[kept], dq[kept], dv[kept], np.zeros(len(kept), bool), np.zeros(len(kept)))).flags
        assert flags.tolist() == [want, want], (p[0, 0], flags)
    unprotected = safety.filtered(apart, np.zeros((2, 3)), owner[:0], dq[:0], dv[:0], FP).flags
    assert unprotected.tolist() == [0, 0]


def test_when_a_protected_link_and_separation_conflict_the_link_gives_way() -> None:
    """MAP 0 at rest, MAP 1 closing on it from behind at 6 m/s 10 m off, MAP 0's protected link to MAP 2 at its
    bound beyond MAP 1, opening: separation asks MAP 0 to flee, the link to stay. Separation is kept to the letter
    and the link's slack gives way (RELAXED): the same command as without the link (separation's slack is priced
    above a link's, safety.SLACK_COST and LINK_COST)."""
    q = np.array([[0.0, 0.0, 20.0], [-10.0, 0.0, 20.0], [-(FP.r - safety.LINK_MARGIN), 0.0, 20.0]])
    p = np.array([[0.0, 0.0, 0.0], [6.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    sep_dq, sep_dv = q[1:2] - q[0], p[1:2] - p[0]
    budget = safety.budget(sep_dq, sep_dv, FP)[0]
    assert budget < -1.0, 'separation asks for no flight: the case tests nothing'
    link = (np.zeros(1, dtype=np.intp), q[2:3] - q[0], p[2:3] - p[0], np.zeros(1, bool), np.zeros(1))
    nominal = np.zeros((1, 3))
    owner = np.zeros(1, dtype=np.intp)
    with_link = safety.filtered(nominal, p[:1], owner, sep_dq, sep_dv, FP, link)
    alone = safety.filtered(nominal, p[:1], owner, sep_dq, sep_dv, FP)
    n = sep_dq[0, :2] / np.linalg.norm(sep_dq[0, :2])
    assert n @ with_link.u[0, :2] <= budget + 1e-6, (with_link.u, budget)
    assert with_link.flags[0] & safety.RELAXED
    assert np.allclose(with_link.u, alone.u, atol=1e-3), (with_link.u, alone.u)


def test_a_map_held_back_from_its_goal_lets_go_of_its_links_for_a_while_and_says_so() -> None:
    """Rule 'release' (safety.held_next): held back by a link (HELD) more than half of d from its goal, a MAP counts
    on (AWAY) and after RELEASE_S protects no link for FREE_S (RELEASED), then counts afresh; held at its goal, or not
    held, it counts nothing; with the rule off it counts on and is never let go."""
    from uav_agent.core.ablation import switched_off
    held_steps, free_steps = round(safety.RELEASE_S / 0.1), round(safety.FREE_S / 0.1)
    held, bits = 0, []
    for _ in range(held_steps + free_steps + 1):
        held, did = safety.held_next(held, safety.HELD, FP.d, FP)
        bits.append(did)
    assert bits[:held_steps] == [safety.AWAY] * held_steps, 'counted while held back far from its goal'
    assert bits[held_steps:held_steps + free_steps] == [safety.RELEASED] * free_steps, 'free of its links for FREE_S'
    assert held == 1 and bits[-1] == safety.AWAY, 'and held again after it, it counts from the start'
    assert safety.held_next(50, safety.HELD, 0.4 * FP.d, FP) == (0, 0), 'held at its goal: a taut link, not a stall'
    assert safety.held_next(50, safety.RELAXED, FP.d, FP) == (0, 0), 'not held back this step'
    with switched_off(['release']):
        assert safety.held_next(held_steps - 1, safety.HELD, FP.d, FP) == (held_steps, safety.AWAY)


def test_a_released_map_protects_no_link_and_its_count_is_carried_on() -> None:
    """policies.needed asks for no link of a MAP rule 'release' sets free; agent.after_filter, which the agent node
    (agent_step) and the batch simulator both call, carries the count on and adds the bits, under the filter only."""
    from uav_agent.core import policies
    from uav_agent.core.agent import after_filter
    from uav_agent.core.allocations.demand.memory import Gossip, Mine
    from uav_agent.core.state import M1, SHARED, UNKEPT, Memory, Reference, Told
    fp = replace(FP, safety='filter')
    relay = Mine.of(Memory(mode=M1, goal=0, bridge=(0, 1), achieved=0b11))._replace(settled=True).memory()
    fellow = [Told(M1, 0, (0, 1), Gossip(settled=True))]
    assert policies.needed(relay, fellow, fp) == [SHARED]
    assert policies.needed(relay, fellow, fp, free=True) == [UNKEPT]
    ref = Reference(np.zeros(3), np.zeros(3), np.array([5.0, 0.0, 20.0]), M1, np.zeros((3, 3)))
    far, near = np.array([0.0, 15.0, 20.0]), np.array([2.0, 1.0, 20.0])
    assert after_filter(7, safety.HELD, far, ref, fp) == (8, safety.HELD | safety.AWAY)
    assert after_filter(7, safety.HELD, near, ref, fp) == (0, safety.HELD), 'on its piece of the edge'
    assert after_filter(7, safety.HELD, far, ref, FP) == (7, safety.HELD), 'the rules (no filter) carry nothing'
