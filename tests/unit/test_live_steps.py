"""The live view's steps (scene.LiveSteps): whatever order the world's topics arrive in, each step is drawn
once, in order, where the world put the MAPs it counted at that step."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from uav_flock_tools.scene import LAG_STEPS, LiveSteps

DT = 0.1


def world(maps: int, steps: int, scheduled: dict[int, int], killed: dict[int, int], seed: int):
    """What a world publishes: per step the ids it senses and where, its metrics rows, its failure events.
    A MAP scheduled at step s is not sensed from s on; one killed at step s is sensed at s, not after."""
    rng = np.random.default_rng(seed)
    sensed, rows, events = [], [], []
    for k in range(steps):
        ids = [i for i in range(maps) if scheduled.get(i, steps) > k and killed.get(i, steps) >= k]
        sensed.append({i: rng.uniform(-100, 100, 3) for i in ids})
        rows.append([k, k * DT, 0.5, 0.1, len(ids), 1, len(ids), 0, 0])
        events += [(k, i, 'scheduled') for i, s in scheduled.items() if s == k]
        events += [(k, i, 'killed') for i, s in killed.items() if s == k]
    return sensed, rows, events


@settings(max_examples=80, deadline=None)
@given(st.integers(2, 6), st.integers(2, LAG_STEPS - 1), st.integers(0, 2**32 - 1), st.data())
def test_any_arrival_order_gives_each_step_once_where_the_world_put_its_maps(maps: int, steps: int, seed: int,
                                                                             data: st.DataObject) -> None:
    victims = data.draw(st.lists(st.integers(0, maps - 1), unique=True, max_size=maps - 1))
    at = {i: data.draw(st.integers(1, steps - 1)) for i in victims}
    kill = {i: data.draw(st.booleans()) for i in victims}
    scheduled = {i: s for i, s in at.items() if not kill[i]}
    killed = {i: s for i, s in at.items() if kill[i]}
    sensed, rows, events = world(maps, steps, scheduled, killed, seed)
    # One queue per topic (each MAP's sensing, /metrics, /events/failure), each in its own order, interleaved.
    topics = [[('sensed', k, i, q) for k in range(steps) for i, q in sensed[k].items() if i == m] for m in range(maps)]
    topics += [[('metrics', row) for row in rows], [('dropped', *e) for e in events]]
    live, frames = LiveSteps(), []
    while any(topics):
        t = data.draw(st.sampled_from([t for t in topics if t]))
        kind, *args = t.pop(0)
        if kind == 'sensed':
            frames += live.sensed(*args)
        elif kind == 'metrics':
            frames += live.metrics(*args)
        else:
            live.dropped(args[0], [args[1]], args[2])
    assert [f.row[0] for f in frames] == list(range(steps))
    for k, f in enumerate(frames):
        assert f.t == rows[k][1] and f.row == rows[k]
        assert f.ids == sorted(sensed[k]), f'step {k}'
        assert np.array_equal(f.q, np.array([sensed[k][i] for i in f.ids]).reshape(-1, 3)), f'step {k}'
    for k in range(1, steps):  # a sphere drawn before and not now is deleted, in that frame
        assert frames[k].gone == sorted(set(frames[k - 1].ids) - set(frames[k].ids)), f'step {k}'
    told = [(k, i) for k, f in enumerate(frames) for i, _ in f.failures]
    assert len({i for _, i in told}) == len(told)  # each failure told once,
    for k, i in told:  # in a frame at or after it that no longer draws the MAP
        assert i not in frames[k].ids and k >= at[i]

def test_a_step_short_of_a_maps_sensing_waits_then_draws_it_where_it_was_last_drawn() -> None:
    sensed, rows, _ = world(3, LAG_STEPS + 8, {}, {}, seed=1)
    live, frames = LiveSteps(), []
    for k, row in enumerate(rows):
        for i, q in sensed[k].items():
            if (k, i) != (5, 1):  # MAP 1's sensing of step 5 never comes
                frames += live.sensed(k, i, q)
        frames += live.metrics(row)
        if k < 5 + LAG_STEPS:
            assert [f.row[0] for f in frames] == list(range(min(k + 1, 5))), f'after step {k}'
    assert [f.row[0] for f in frames] == list(range(len(rows)))
    assert np.array_equal(frames[5].q[1], sensed[4][1]) and np.array_equal(frames[5].q[0], sensed[5][0])


def test_the_view_begins_with_its_first_whole_step() -> None:
    """A viewer that hears MAP 0's sensing only from step 3 on (its subscription matched late, past the
    history) draws nothing of steps 0-2, not a formation without MAP 0."""
    sensed, rows, _ = world(3, LAG_STEPS + 8, {}, {}, seed=2)
    live, frames = LiveSteps(), []
    for k, row in enumerate(rows):
        frames += live.metrics(row)
        for i, q in sensed[k].items():
            if i != 0 or k >= 3:
                frames += live.sensed(k, i, q)
    assert [f.row[0] for f in frames] == list(range(3, len(rows)))
    assert all(f.ids == [0, 1, 2] for f in frames)


def test_sensing_with_no_metrics_keeps_a_bounded_number_of_steps() -> None:
    """A viewer that hears the MAPs' sensing and no metrics (yet) holds the newest steps only."""
    sensed, rows, _ = world(2, 10 * LAG_STEPS, {}, {}, seed=3)
    live = LiveSteps()
    for k in range(len(rows)):
        for i, q in sensed[k].items():
            assert live.sensed(k, i, q) == []
    assert sorted(live.heard) == list(range(len(rows) - 4 * LAG_STEPS, len(rows)))
    frames = live.metrics(rows[-1])
    assert len(frames) == 1 and frames[0].ids == [0, 1] and np.array_equal(frames[0].q[1], sensed[-1][1])
