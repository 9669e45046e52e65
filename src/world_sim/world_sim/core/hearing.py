"""What the channel between MAPs lets them hear, as the world measures it for the records.

Beside the paper's lambda2 of the disc graph, a run under a channel (a scenario's `links:`, uav_agent/core/
links.py) records per step: lambda2 and components of the usable graph (links whose delivery probability is
at least links.USABLE) and of the heard graph (pairs of which one heard the other in the last second), the
share of neighbour states heard at the step, and the age of the oldest state a MAP used. The world hears by
the MAPs' own road (uav_agent/core/ear.py), the states without what they say: what a lockstep run's MAPs
heard, to the state.
"""
from __future__ import annotations

import numpy as np

from uav_agent.core import links
from uav_agent.core.ear import Ear, Heard, Sent, hear

from . import physics
from .scenario import Scenario

LINK_COLUMNS = ('usable_fiedler', 'usable_components', 'heard_fiedler', 'heard_components', 'heard_share',
                'oldest_used')
LINK_FMT = ('%.10g', '%d', '%.10g', '%d', '%.10g', '%d')
_UNREAD = np.zeros(3)  # a state's velocity, which the records never read
HEARD_WINDOW_S = 1.0  # a pair is in the heard graph while a state went either way this recently


def summary(metrics: np.ndarray) -> str:
    """What a run's MAPs heard, in a line: metrics rows with LINK_COLUMNS after the nine of records.METRICS_COLUMNS."""
    usable, heard, share, oldest = (metrics[:, 9 + LINK_COLUMNS.index(c)] for c in
                                    ('usable_fiedler', 'heard_fiedler', 'heard_share', 'oldest_used'))
    return (f'usable graph connected {100 * np.mean(usable > 0):.1f} % of the run, heard graph '
            f'{100 * np.mean(heard > 0):.1f} %; {100 * share.mean():.1f} % of neighbour states heard, oldest used '
            f'{int(oldest.max())} steps')


class Hearing:
    """The channel's side of a run's metrics, one row per step (LINK_COLUMNS)."""

    def __init__(self, scenario: Scenario) -> None:
        self.scenario = scenario
        self.window = max(int(round(HEARD_WINDOW_S / scenario.dt)), 1)
        self.last: dict[tuple[int, int], int] = {}  # (receiver, sender) ids -> the last step heard
        self.ears: dict[int, Ear] = {}

    def row(self, k: int, ids: np.ndarray, q: np.ndarray, pairs: np.ndarray) -> np.ndarray:
        """Step k's row, from the live MAPs (ids, q, rows alike) and their ordered neighbour pairs (rows)."""
        s, n = self.scenario, len(ids)
        r = s.flock.r
        dist = np.linalg.norm(q[pairs[:, 0]] - q[pairs[:, 1]], axis=1)
        usable = pairs[links.delivery(s.links, dist, r) >= links.USABLE]
        u_comp = physics.components(usable, n)
        bounds = np.searchsorted(pairs[:, 0], np.arange(n + 1)).tolist()  # pairs come grouped by receiver row
        sent = [Sent(int(i), Heard(q[j], _UNREAD, 0.0, None)) for j, i in enumerate(ids.tolist())]  # type: ignore[arg-type]
        ears = [self.ears.setdefault(i, Ear(s.links, s.seed, i, hearsay=False)) for i in ids.tolist()]
        got = hear(ears, k, q, [[sent[j] for j in pairs[bounds[m]:bounds[m + 1], 1].tolist()] for m in range(n)], r)
        ok = np.concatenate([np.zeros(0, dtype=bool), *got])
        for a, b in ids[pairs[ok]].tolist():
            self.last[(a, b)] = k
        self.last = {pair: at for pair, at in self.last.items() if at > k - self.window}
        row_of = {int(i): n_ for n_, i in enumerate(ids.tolist())}
        heard_pairs = np.array(sorted({(row_of[a], row_of[b]) for a, b in self.last if a in row_of and b in row_of}
                                      | {(row_of[b], row_of[a]) for a, b in self.last if a in row_of and b in row_of}),
                               dtype=np.intp).reshape(-1, 2)
        h_comp = physics.components(heard_pairs, n)
        oldest = max([0, *(ear.oldest(k) for ear in ears)])
        return np.array([physics.fiedler(usable, n, u_comp), u_comp, physics.fiedler(heard_pairs, n, h_comp), h_comp,
                         float(ok.mean()) if len(ok) else 1.0, oldest], dtype=float)
