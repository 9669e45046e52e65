"""The radio between MAPs (core/links.py): each decision a pure function of its inputs, the channel's
statistics as the scenario states them, and what a MAP holds of its neighbours' states (Inbox)."""
from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from uav_agent.core import ablation
from uav_agent.core.agent import Said
from uav_agent.core.ear import PASSED_ON, Ear, Heard, Passed, Sent, hear, heard_from
from uav_agent.core.links import LOST, USABLE, Inbox, Links, deliver, delivery, heard, lost, reach
from uav_agent.core.potentials import bump
from uav_agent.core.state import M2, Told
from uav_flock_tools.batch import BatchSimulator
from world_sim.core.hearing import LINK_COLUMNS
from world_sim.core.records import METRICS_COLUMNS
from world_sim.core.scenario import to_doc
from world_sim.shipped import load_scenario

R = 24.0
LINKS = st.builds(Links, st.sampled_from(['disc', 'alpha']), st.floats(0.0, 0.95), st.floats(0.0, 0.9),
                  st.sampled_from([1.0, 10.0, 25.0]), st.integers(0, 3), st.integers(3, 12)).filter(
    lambda c: c.burst == 1.0 or c.burst * (1 - c.loss) >= 1)


def pairs(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    rx, tx = rng.integers(0, 500, n), rng.integers(0, 500, n)
    q_rx = rng.uniform(-100, 100, (n, 3))
    return rx, tx, q_rx, q_rx + rng.uniform(-R / 2, R / 2, (n, 3))


@settings(max_examples=40, deadline=None)
@given(LINKS, st.integers(0, 2**32), st.integers(0, 10**6))
def test_a_decision_is_the_same_whoever_asks_with_whatever_else(links: Links, seed: int, k: int) -> None:
    """The node decides for its own links, the batch simulator for all at once, in any order."""
    rx, tx, q_rx, q_tx = pairs(40, k)
    together = heard(links, seed, k, rx, tx, q_rx, q_tx, R)
    alone = [heard(links, seed, k, rx[i:i + 1], tx[i:i + 1], q_rx[i:i + 1], q_tx[i:i + 1], R)[0] for i in range(40)[::-1]]
    assert together.tolist() == alone[::-1]
    assert heard(links, seed, k, rx, tx, q_rx, q_tx, R).tolist() == together.tolist()


def test_the_papers_channel_hears_everything_in_range() -> None:
    rx, tx, q_rx, q_tx = pairs(500, 1)
    assert Links().perfect and heard(Links(), 3, 7, rx, tx, q_rx, q_tx, R).all()
    assert not Links(loss=0.1).perfect and not Links(latency=1).perfect and not Links(delivery='alpha').perfect


@pytest.mark.parametrize('loss, burst', [(0.3, 1.0), (0.3, 20.0), (0.5, 5.0)])
def test_losses_have_the_stated_mean_and_burst_length(loss: float, burst: float) -> None:
    """2000 links over 400 steps: the lossy share and the mean run of losses, within sampling error."""
    links, n = Links(loss=loss, burst=burst), 2000
    state = np.array([lost(links, 11, k, np.arange(n), np.arange(n) + 1) for k in range(400)])
    runs = np.diff(np.flatnonzero(np.diff(np.r_[0, state[:, :500].T.ravel(), 0]) != 0))[::2]
    assert abs(state.mean() - loss) < 0.01
    expected = burst if burst > 1 else 1 / (1 - loss)
    assert abs(runs.mean() - expected) < 0.1 * expected, (runs.mean(), expected)


def test_alpha_delivers_with_the_papers_probability_at_each_distance() -> None:
    links, n = Links(delivery='alpha', z1=0.8), 20000
    for dist in (10.0, 0.85 * R, 0.95 * R, R + 1):
        q_tx = np.zeros((n, 3))
        q_tx[:, 0] = dist
        share = heard(links, 5, 9, np.arange(n), np.arange(n) + 7, np.zeros((n, 3)), q_tx, R).mean()
        assert abs(share - float(bump(dist, 0.8 * R, R))) < 0.015, (dist, share)


def test_a_state_is_used_from_latency_until_ttl_steps_after_its_step() -> None:
    box: Inbox[str] = Inbox(Links(loss=0.5, latency=2, ttl=5))
    box.receive(10, [4, 7], ['4@10', '7@10'], [12, 12])
    assert box.usable(11) == [], 'not before its latency'
    assert box.usable(12) == [(4, 2, '4@10'), (7, 2, '7@10')]
    box.receive(13, [7], ['7@13'], [15])
    assert box.usable(14) == [(4, 4, '4@10'), (7, 4, '7@10')], 'the newer state is not usable yet'
    assert box.usable(15) == [(4, 5, '4@10'), (7, 2, '7@13')]
    assert box.usable(16) == [(7, 3, '7@13')], 'past its ttl a state is forgotten'
    assert 4 not in box.held


@pytest.mark.parametrize('links, says', [
    ({'loss': 1.0}, 'links.loss: must be below 1'),
    ({'latency': -1}, 'links.latency: must be a non-negative integer'),
    ({'delivery': 'cone'}, 'links.delivery: must be one of disc, alpha'),
    ({'latency': 4, 'ttl': 2}, 'links.ttl: must be at least links.latency'),
    ({'burst': 1.5, 'loss': 0.6}, 'links.burst: at loss 0.6'),
    ({'jitter': 2}, 'links.jitter: unknown key'),
])
def test_a_bad_channel_is_one_line_and_exit_2(tmp_path: Path, links: dict, says: str) -> None:
    doc = to_doc(dataclasses.replace(load_scenario('paper'), duration=1.0))
    doc['links'] = links
    (tmp_path / 'bad.yaml').write_text(yaml.safe_dump(doc))
    proc = subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'sim', '--scenario', str(tmp_path / 'bad.yaml'),
                           '--out', str(tmp_path / 'run')], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1 and says in proc.stderr, proc.stderr
    assert not (tmp_path / 'run').exists()


def test_a_run_under_a_channel_records_what_the_maps_heard() -> None:
    """metrics.csv gains hearing.LINK_COLUMNS under a channel, and only then."""
    s = load_scenario('paper').with_overrides(maps=30, duration=8.0)
    assert BatchSimulator(s).run().metrics.shape[1] == len(METRICS_COLUMNS)
    m = BatchSimulator(dataclasses.replace(s, links=Links(loss=0.3, latency=2, ttl=6))).run().metrics
    col = {c: m[:, i] for i, c in enumerate(METRICS_COLUMNS + LINK_COLUMNS)}
    assert np.array_equal(col['usable_fiedler'], col['fiedler']), 'under disc the usable graph is the disc graph'
    assert abs(col['heard_share'][10:].mean() - 0.7) < 0.03
    assert col['oldest_used'].max() <= 6 and col['oldest_used'][5:].min() >= 2, 'ages from latency to ttl'
    assert np.all((col['heard_components'] >= 1) & (col['usable_components'] >= col['components']))


def test_a_stale_state_stands_where_its_sender_flew_on_says_its_age_and_one_gone_out_of_range_is_dropped() -> None:
    said = Said(0, Told(0, -1, None))
    held = [(3, 0, Heard(np.array([10.0, 0, 20]), np.array([5.0, 0, 0]), 2.0, said)),
            (5, 4, Heard(np.array([10.0, 0, 20]), np.array([5.0, 0, 0]), 1.0, said)),
            (8, 4, Heard(np.array([20.0, 0, 20]), np.array([5.0, 0, 0]), 0.0, said))]
    hood = heard_from(held, 0.1, np.zeros(3) + [0, 0, 20], R)
    assert hood.q[:, 0].tolist() == [10.0, 12.0, 22.0], 'age 0 as heard; age 4 flown on 4 x 0.1 s at 5 m/s'
    assert hood.n_users.tolist() == [2.0, 1.0, 0.0] and len(hood.told) == 3
    assert hood.age.tolist() == pytest.approx([0.0, 0.4, 0.4]), 'how old each state is, for the filter\'s link margins'
    far = heard_from(held, 0.1, np.array([-5.0, 0, 20]), R)
    assert far.q[:, 0].tolist() == [10.0, 12.0], 'MAP 8, flown on to 27 m away, is taken for gone'
    assert far.age.tolist() == pytest.approx([0.0, 0.4])


def test_a_neighbour_whose_own_states_are_lost_is_heard_through_another_as_old_as_its_step() -> None:
    """Rule 'hearsay' (ear.Ear.hear_passed): a MAP passes on its nearest neighbours' states; a receiver uses one it
    holds nothing newer of, aged from the state's own step, usable when the message that carried it is; of
    itself it takes nothing."""
    said, here = Said(0, Told(M2, 0, None)), np.array([0.0, 0, 20])
    channel = Links(loss=0.3, burst=20.0, latency=1, ttl=5)
    a = Ear(channel, 0, 1)
    a.take(0, [Sent(2, Heard(np.array([10.0, 0, 20]), np.zeros(3), 0.0, said)),
               Sent(3, Heard(np.array([30.0, 0, 20]), np.zeros(3), 0.0, said))], np.array([1, 1]))
    assert a.neighbourhood(0, 0.1, here, R).q.shape == (0, 3), 'latency 1: nothing usable yet'
    a.neighbourhood(1, 0.1, here, R)
    assert [(p.id, p.step) for p in a.passed] == [(2, 0)], 'MAP 3 lies beyond r: not passed on'
    b = Ear(channel, 0, 2)
    b.take(2, [Sent(1, Heard(np.array([5.0, 0, 20]), np.zeros(3), 0.0, said), a.passed)], np.array([LOST]))
    assert b.inbox.held == {}, 'what a lost message passed on is lost with it'
    b.take(2, [Sent(1, Heard(np.array([5.0, 0, 20]), np.zeros(3), 0.0, said), a.passed)], np.array([3]))
    assert sorted(b.inbox.held) == [1], 'its own state passed back is not taken'
    assert b.neighbourhood(2, 0.1, here, R).q.shape == (0, 3), 'usable a step after the message'
    assert [(j, age) for j, age, _ in b.inbox.usable(3)] == [(1, 1)]
    c = Ear(channel, 0, 3)
    c.take(4, [Sent(2, Heard(np.array([12.0, 0, 20]), np.zeros(3), 0.0, said))], np.array([5]))
    c.hear_passed(5, a.passed)
    assert [at for _, at, _ in c.inbox.held[2]] == [4], 'an older state passed on is ignored'
    c.hear_passed(6, [Passed(7, 3, Heard(np.array([1.0, 0, 20]), np.zeros(3), 0.0, said))])
    assert [(j, age) for j, age, _ in c.inbox.usable(6)] == [(2, 2), (7, 3)], 'aged from its own step (3), not 5'
    assert [j for j, _, _ in c.inbox.usable(9)] == [2], 'the state of step 3 forgotten once older than ttl (5)'
    with ablation.switched_off(['hearsay']):
        d = Ear(Links(loss=0.3), 0, 4)
        d.take(0, [Sent(1, Heard(np.array([5.0, 0, 20]), np.zeros(3), 0.0, said), a.passed)], np.array([0]))
        assert sorted(d.inbox.held) == [1]


def test_every_reader_hears_through_the_channel_s_one_decision() -> None:
    """ear.hear asks links.deliver once for all its readers: what it takes in is what deliver decides for each
    (reader, sender, step, positions), latency included, whoever asks and however the readers are grouped."""
    said = Said(0, Told(M2, 0, None))
    channel = Links(delivery='alpha', z1=0.5, loss=0.3, burst=4.0, latency=2, ttl=6)
    rng = np.random.default_rng(3)
    here = np.c_[rng.uniform(0, 40, (6, 2)), np.full(6, 20.0)]
    sent = [[Sent(j, Heard(here[j], np.zeros(3), 0.0, said)) for j in range(6) if j != i] for i in range(6)]
    for k in (0, 7, 31):
        together = [Ear(channel, 11, i) for i in range(6)]
        heard_together = hear(together, k, here, sent, R)
        for i in range(6):
            alone = Ear(channel, 11, i)
            assert np.array_equal(hear([alone], k, here[i:i + 1], [sent[i]], R)[0], heard_together[i])
            want = deliver(channel, 11, k, np.full(5, i), np.array([m.id for m in sent[i]]), np.tile(here[i], (5, 1)),
                           here[[m.id for m in sent[i]]], R)
            assert np.array_equal(heard_together[i], want != LOST)
            assert set(want[want != LOST].tolist()) <= {k + 2}, 'usable latency steps after the step'
            assert sorted(together[i].inbox.held) == [m.id for m, w in zip(sent[i], want) if w != LOST]


def test_what_neighbours_pass_on_changes_a_run_only_under_a_lossy_channel_and_the_demand_allocation() -> None:
    """The batch simulator delivers what each heard message passes on (the lockstep test in tests/ros holds the
    agent nodes to the same run): with rule 'hearsay' off the same lossy run differs; over the paper's channel
    nothing is passed on at all, nor under Algorithm 2 (policies.hearsay)."""
    paper = dataclasses.replace(load_scenario('paper').with_overrides(maps=30, duration=6.0),
                                links=Links(loss=0.3, burst=5.0, latency=1, ttl=4))
    s = dataclasses.replace(paper, flock=dataclasses.replace(paper.flock, allocation='demand'))
    sim = BatchSimulator(s)
    on = sim.run().trajectory
    assert any(ear.passed for ear in sim.ears)
    with ablation.switched_off(['hearsay']):
        off = BatchSimulator(s).run().trajectory
    assert not np.array_equal(on, off)
    assert all(ear.inbox is None for ear in BatchSimulator(load_scenario('paper').with_overrides(maps=30, duration=1.0)).ears)
    assert paper.flock.allocation == 'algorithm2'
    alg2 = BatchSimulator(dataclasses.replace(paper, duration=2.0))
    alg2.run()
    assert not any(ear.passed for ear in alg2.ears)


def test_a_map_passes_on_its_nearest_neighbours_only() -> None:
    said, here = Said(0, Told(M2, 0, None)), np.array([0.0, 0, 20])
    ear = Ear(Links(loss=0.3), 0, 0)
    ids = list(range(1, PASSED_ON + 3))
    ear.take(0, [Sent(i, Heard(np.array([2.0 * j, 0, 20]), np.zeros(3), 0.0, said)) for i, j in zip(ids, reversed(ids))],
             np.zeros(len(ids), dtype=int))
    ear.neighbourhood(0, 0.1, here, R)
    assert [p.id for p in ear.passed] == ids[2:], 'the PASSED_ON nearest (ids listed farthest first), ascending id'


def test_chains_are_laid_inside_what_the_channel_delivers() -> None:
    assert reach(Links(), R) == 0.0, 'under disc: r itself'
    far = reach(Links(delivery='alpha', z1=0.8), R)
    assert far == pytest.approx(0.9 * R) and delivery(Links(delivery='alpha'), np.array([far]), R)[0] == pytest.approx(USABLE)
    assert dataclasses.replace(load_scenario('paper'), links=Links(delivery='alpha')).flock.link_reach == pytest.approx(0.9 * R)
