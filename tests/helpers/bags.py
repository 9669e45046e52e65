"""What a recorded run's bag must hold: every message world_sim sent and every one it used, step by step."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from uav_flock_tools import bag
from world_sim.core.records import read_csv


def assert_nothing_lost(run: Path) -> bag.BagRun:
    """Per step k: the world sensed S, dropped K as dead, and heard commands C and states T.

    Every sensing the world sent is in the bag, and so is the command of every MAP the world did not
    drop (C >= S - K). A MAP SIGKILLed during the step may or may not have published before dying; what
    it published is there too, in order (C <= T <= S).
    """
    b = bag.load(run / 'bag')
    metrics = read_csv(run / 'metrics.csv')
    traj = read_csv(run / 'trajectory.csv')
    assert len(b.metrics) == len(metrics['step']) > 0, 'one /metrics message per step the world recorded'
    assert np.array_equal(b.metrics[:, 0], metrics['step'])
    killed: dict[int, set[int]] = {}
    for step, ids, cause in b.failures:
        if cause == 'killed':
            killed.setdefault(step, set()).update(ids)
    for k in metrics['step'].astype(int).tolist():
        sensed = b.heard['sensing'].get(k, set())
        assert sensed == set(traj['id'][traj['step'] == k].astype(int).tolist()), f'step {k}: sensing'
        assert sensed == set(b.association[k][0].tolist()), f'step {k}: association'
        commands = b.heard['cmd'].get(k, set())
        states = b.heard['state'].get(k, set())
        # A MAP killed while its step-k command was on its way may reach the world and not the recorder:
        # the world then steps on and drops it at k + 1.
        dying = killed.get(k, set()) | killed.get(k + 1, set())
        assert sensed - dying <= commands <= states <= sensed, \
            f'step {k}: sensed {sorted(sensed)}, killed {sorted(killed.get(k, ()))}, commands {sorted(commands)}, ' \
            f'states {sorted(states)}'
    expected = sum(len(b.heard['sensing'][k]) for k in b.heard['sensing'])
    published = sum(n for t, n in b.counts.items() if t.endswith('/sensing'))
    if 'sensing sent again' in (run / 'logs' / 'world.log').read_text():  # a stalled step was repeated
        assert published > expected
    else:
        assert published == expected, 'one sensing message per MAP and step, none lost'
    return b
