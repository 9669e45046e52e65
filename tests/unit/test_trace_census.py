"""The census of `trace STUDY --outages` (uav_flock_tools/trace.py): outage time after first convergence over a
study's runs, by what began each outage and whether the formation had formed by then."""
from __future__ import annotations

from uav_flock_tools.trace import Census, Outage, Traced, census, census_lines

FIRST = 'a link kept by neither end, of a MAP on its first flight'
MOVED = 'a link kept by neither end, of a MAP in transit'


def test_each_outage_counts_once_by_what_began_it_and_whether_its_run_had_formed() -> None:
    runs = [(30.0, 60.0, 45.0, Traced(2, [Outage(32.0, 35.5, FIRST), Outage(50.0, 51.0, MOVED)])),
            (20.0, 60.0, None, Traced(1, [Outage(21.0, 22.0, FIRST)])),  # never formed: all before it
            (40.0, 60.0, 41.0, Traced(0, []))]
    c = census(runs)
    assert c.runs == 3 and c.window == 30.0 + 40.0 + 20.0
    assert c.apart == {(FIRST, True): (4.5, 2), (MOVED, False): (1.0, 1)}
    lines = census_lines(c)
    assert lines[0] == 'outages after first convergence, 3 runs, 90.0 s after it in all; apart 5.5 s (6.11 %):'
    assert lines[2].split() == [*FIRST.split(), 'not', 'yet', '4.5', '5.00', '%', '2']  # the most time first
    assert lines[3].split() == [*MOVED.split(), 'after', '1.0', '1.11', '%', '1']


def test_a_census_of_runs_that_never_split_says_so() -> None:
    c = census([(10.0, 60.0, 30.0, Traced(0, []))])
    assert c == Census({}, 50.0, 1)
    assert census_lines(c)[-1] == '  none: one network from each first convergence to its end'
