"""What world_sim watches besides the step: the processes of the MAPs it waits for, and the recorder
(mixed into WorldNode).

A MAP whose process is gone (or that `uav-flock kill` ended inside one) is dropped within one liveness check;
a step that stalls while every process lives has its sensing sent again; a scheduled failure SIGKILLs the
processes whose MAPs have all failed. The recorder paces a lockstep run (RECORDER_MAX_LAG_STEPS) until it
stops answering, and at exit what the world published last reaches every reader before its writers go.
"""
from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path
from typing import Any, Optional

import numpy as np
from rclpy.duration import Duration
from std_msgs.msg import Int64

from uav_flock_ros import convert
from uav_flock_ros.processes import CRASH_DIR, process_alive
from uav_flock_ros.qos import RECORDER_MAX_LAG_STEPS

from .core.model import Sensed, World
from .core.scenario import Scenario

LIVENESS_PERIOD_S = 0.2  # how often the processes of MAPs we wait for are checked
RECORDER_TIMEOUT_S = 10.0  # a recorder that writes nothing new this long while we wait for it is given up on
FLUSH_S = 1.0  # at exit, how long the last steps' samples may take to be acknowledged by every reader
SHOWN_WAITING = 12  # MAP ids a stall's log line names (a city's first step waits for hundreds)
# A step stalled this long (every process alive) has its sensing sent again, then after twice as long, and
# so on: step 0 of 90 processes spends ten seconds or more in discovery, and every repeat makes each MAP
# it reaches publish its state once more, which is CPU the discovery needs.
RESEND_AFTER_S = 2.0


class Watch:
    """The liveness checks and the recorder's pace of a WorldNode."""

    # The WorldNode's, which these methods use (world_node.py).
    world: World
    scenario: Scenario
    sensed: Optional[Sensed]
    realtime: bool
    record: bool
    recorded: int
    recorder_moved: float
    held: bool
    commands: dict[int, Any]
    sensing_pubs: list[Any]
    metrics_pub: Any
    assoc_pub: Any
    failure_pub: Any
    pid_table: Optional[Path]
    step_started: float
    step_resends: int
    resent: int

    def recorder_behind(self) -> bool:
        """The recorder's last complete step is too far back. Before a scheduled failure SIGKILLs agents it
        must hold the step just ended: a command already used and not yet recorded would die with its writer."""
        lag = 1 if self.world.failing_now else RECORDER_MAX_LAG_STEPS
        return self.record and self.world.k - self.recorded > lag

    def on_recorder(self, msg: Int64) -> None:
        if int(msg.data) > self.recorded:
            self.recorded = int(msg.data)
            self.recorder_moved = time.monotonic()
        if self.held and not self.recorder_behind():
            self.held = False
            self.begin_step()

    def recorder_gone(self) -> bool:
        """A recorder that stopped answering is not waited for any longer: the run goes on unrecorded."""
        if time.monotonic() - self.recorder_moved < RECORDER_TIMEOUT_S:
            return False
        self.get_logger().error(f'the recorder wrote nothing new for {RECORDER_TIMEOUT_S:g} s: going on without it')
        self.record = False
        return True

    def flush(self) -> None:
        """Wait, within FLUSH_S, until every reader holds what the world published last.

        An interrupted run ends up to RECORDER_MAX_LAG_STEPS ahead of the recorder: a writer deleted with those
        samples unacknowledged takes them with it, and the bag would miss steps that metrics.csv holds.
        """
        deadline = time.monotonic() + FLUSH_S
        for pub in (self.metrics_pub, self.failure_pub, self.assoc_pub, *self.sensing_pubs):
            if not pub.wait_for_all_acked(Duration(seconds=max(deadline - time.monotonic(), 0.0))):
                return

    def drop(self, ids: np.ndarray, cause: str) -> None:
        ids = np.asarray(sorted(int(i) for i in ids), dtype=np.intp)
        self.world.drop(ids, cause)
        for i in ids.tolist():
            self.commands.pop(i, None)  # a dropped MAP flies no command any more
        self.failure_pub.publish(convert.FailureData(self.world.k, tuple(ids.tolist()), cause).to_msg(self.header()))
        # INFO, not WARN: `up` shows warnings on the terminal, where the progress line below already says it.
        self.get_logger().info(f'step {self.world.k}: dropped MAPs {ids.tolist()} ({cause})')
        print(f't = {self.world.k * self.scenario.dt:5.1f} s  dropped MAPs {ids.tolist()} ({cause})', flush=True)

    def kill_processes(self, ids: np.ndarray) -> None:
        """A scheduled failure is a real one: SIGKILL each agent process whose MAPs have all failed.

        A process that hosts live MAPs too (agents packed K per process) is spared; its failed MAPs fall
        silent on the failure event instead.
        """
        table = self.pids()
        hosted: dict[int, list[int]] = {}
        for i, pid in table.items():
            hosted.setdefault(pid, []).append(i)
        for pid, maps in hosted.items():
            if set(ids.tolist()) & set(maps) and not any(self.world.alive[i] for i in maps if i < self.scenario.maps):
                try:
                    os.kill(pid, signal.SIGKILL)
                except (ProcessLookupError, PermissionError):
                    pass

    def pids(self) -> dict[int, int]:
        if self.pid_table is None or not self.pid_table.exists():
            return {}
        try:
            return {int(k): int(v) for k, v in json.loads(self.pid_table.read_text()).items()}
        except (ValueError, OSError):
            return {}

    def crashed(self, i: int) -> bool:
        """`uav-flock kill` ended MAP i's node inside its process (the file it leaves beside pids.json)."""
        return self.pid_table is not None and (self.pid_table.parent / CRASH_DIR / str(i)).exists()

    def check_liveness(self) -> None:
        """Drop the MAPs we wait for, or their neighbours, whose process is gone; a slow living MAP is waited for."""
        s = self.sensed
        if s is None:
            return
        # realtime waits for no one, so every live MAP is watched
        waiting = [i for i in s.ids.tolist() if self.world.alive[i] and (self.realtime or i not in self.commands)]
        if not waiting:
            return
        # A MAP of this host whose process is gone, or whose node `kill` ended inside a process that lives on
        # (it names the MAP in the run's crash folder first). One on another host (no pid here): DDS no longer
        # matches its reader, once its participant left or its lease expired (link down).
        table = self.pids()
        # Once the step has stalled, their neighbours too (watched); before that only they: a MAP on another host
        # has only the graph to say it left, which is asked about no more MAPs than a stall needs.
        stalled = self.step_resends > 0 or time.monotonic() - self.step_started > RESEND_AFTER_S
        gone = [i for i in (watched(s, waiting, self.world.alive) if stalled else waiting)
                if (i in table and (not process_alive(table[i]) or self.crashed(i)))
                or (i not in table and self.sensing_pubs[i].get_subscription_count() == 0)]
        if gone:
            self.drop(np.array(gone), 'killed')
            if not self.realtime:
                self.maybe_advance()
        elif not self.realtime and time.monotonic() - self.step_started > RESEND_AFTER_S * 2 ** self.step_resends:
            # Every process lives, yet the step stalls: a first sample after discovery can go missing.
            # Sending the step's sensing again is harmless: each MAP answers a repeat with its state and
            # (if it already has one) its command of the step once more. It goes to the MAPs we wait for
            # and to their neighbours, whose states they may be missing.
            # Step 0's first sample is the one discovery loses most: its repeat is part of starting, not a stall
            # worth a line at the end (the log still says it).
            self.resent += int(s.k > 0)
            self.step_resends += 1
            stalled = set(waiting)
            again = set(stalled)
            for row, i in enumerate(s.ids.tolist()):
                if i in stalled:
                    again.update(s.ids[s.neighbours(row)].tolist())
            # A delay, not a change: lockstep results do not depend on it. Logged, counted, said once at the end.
            named = ', '.join(map(str, waiting[:SHOWN_WAITING])) + (', ...' if len(waiting) > SHOWN_WAITING else '')
            self.get_logger().info(f'step {s.k} stalled {time.monotonic() - self.step_started:.0f} s waiting for '
                                   f'{len(waiting)} MAPs ({named}): sensing sent again to them and their '
                                   f'neighbours (time {self.step_resends} this step)')
            self.step_started = time.monotonic()
            self.publish_sensing(self.header(), again)


def watched(s: Sensed, waiting: list[int], alive: np.ndarray) -> list[int]:
    """The MAPs whose liveness a stalled step depends on: those it waits for and their live neighbours.

    A MAP we wait for may itself wait for a neighbour whose command is in: one whose node `kill` ended after it
    sent that command, its state of the step lost with its writer before the two matched. Dropping it (the
    failure event) lets the waiting MAP step without it; waiting for its state would stall the run for good.
    """
    rows = {i: row for row, i in enumerate(s.ids.tolist())}
    out = set(waiting)
    for i in waiting:
        out.update(j for j in s.ids[s.neighbours(rows[i])].tolist() if alive[j])
    return sorted(out)
