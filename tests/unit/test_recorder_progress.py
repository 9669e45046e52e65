"""The recorder's progress: the last step of which the bag holds everything world_sim used."""
from __future__ import annotations

from uav_flock_tools.recorder import StepProgress


def feed(p: StepProgress, step: int, maps: list[int], kinds: tuple[str, ...] = ('state', 'cmd')) -> None:
    for i in maps:
        for kind in kinds:
            p.map_message(kind, i, step)


def test_a_step_is_whole_only_with_every_live_maps_state_and_command() -> None:
    p = StepProgress(3, lockstep=True)
    feed(p, 0, [0, 1, 2])
    p.metrics = 0
    assert p.advance() and p.step == 0
    feed(p, 1, [0, 1, 2], ('state',))
    feed(p, 1, [0, 1], ('cmd',))
    p.metrics = 1
    assert not p.advance() and p.step == 0, 'MAP 2 command of step 1 is not in yet'
    feed(p, 1, [2], ('cmd',))
    assert p.advance() and p.step == 1


def test_a_step_waits_for_metrics_and_a_late_writer_catches_up_in_order() -> None:
    p = StepProgress(2, lockstep=True)
    for k in range(5):
        feed(p, k, [0])
    assert not p.advance(), 'no /metrics yet'
    p.metrics = 4
    assert not p.advance() and p.step == -1, 'MAP 1 has sent nothing'
    for k in range(3):  # its writer hands over its history once matched
        feed(p, k, [1])
    assert p.advance() and p.step == 2
    feed(p, 4, [1])
    assert not p.advance() and p.step == 2, 'step 4 does not vouch for step 3'
    feed(p, 3, [1])
    assert p.advance() and p.step == 4


def test_a_message_that_comes_late_holds_the_step_until_it_is_in() -> None:
    p = StepProgress(2, lockstep=True)
    feed(p, 0, [0, 1])
    feed(p, 1, [0, 1], ('state',))
    feed(p, 1, [0], ('cmd',))  # MAP 1's command of step 1 is lost on its way, for now
    for k in (2, 3):
        feed(p, k, [0, 1])
    p.metrics = 3
    assert p.advance() and p.step == 0, 'held at the step before the missing command'
    feed(p, 1, [1], ('cmd',))  # repaired
    assert p.advance() and p.step == 3
    feed(p, 2, [0, 1])  # a step said again (world_sim repeats a stalled one): counted once
    feed(p, 4, [0, 1])
    p.metrics = 4
    assert p.advance() and p.step == 4


def test_a_dropped_map_is_waited_for_no_longer() -> None:
    p = StepProgress(2, lockstep=True)
    feed(p, 0, [0, 1])
    feed(p, 1, [0])
    p.metrics = 1
    assert p.advance() and p.step == 0
    p.dropped.add(1)
    assert p.advance() and p.step == 1


def test_realtime_follows_metrics_alone() -> None:
    p = StepProgress(2, lockstep=False)
    feed(p, 0, [0])
    p.metrics = 3
    assert p.advance() and p.step == 3
