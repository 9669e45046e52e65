"""One agent process: the MAPs it hosts (`--ids`), on one DDS participant, until the run ends or a signal.

`uav_agent_node --ids 0,1,2` (console script, started by `up` and `agents`) makes an AgentNode per MAP, spins
them on one executor, ends a MAP that `uav-flock kill` names (SIGUSR1), and makes the participant anew when a
step stalls on a connection that carries nothing (recovery.RENEW_AFTER_S, RENEW_MIDWAY_TRIES) or at SIGUSR2.
"""
from __future__ import annotations

import argparse
import signal
import sys
import time
from pathlib import Path
from types import FrameType
from typing import Callable, Optional

import rclpy
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.executors import Executor
from rclpy.signals import SignalHandlerOptions
from uav_flock_ros.executors import PARAMETER_ERRORS, StopSignals, checked_ros_args, make_executor, unheeded
from uav_flock_ros.processes import leave_after

from .agent_node import AgentNode
from .recovery import RENEW_AFTER_S, RENEW_MIDWAY_TRIES

RENEW_TIMES = 3  # the most times a process makes its participant anew
RENEW_WAIT_S = 30.0  # how long the new nodes may take to have their sensing before the old ones go anyway
FLUSH_S = 1.0  # at the end, how long the last states and commands may take to be acknowledged by every reader


def parse_ids(argv: list[str]) -> list[int]:
    parser = argparse.ArgumentParser(prog='uav_agent_node', description='Run one or more MAP agent nodes.')
    parser.add_argument('--ids', required=True, help='MAP ids hosted by this process, e.g. 3 or 0,1,2')
    args = parser.parse_args(argv)
    try:
        ids = [int(v) for v in args.ids.split(',') if v.strip()]
    except ValueError:
        parser.error(f'--ids: expected integers separated by commas, got {args.ids!r}')
    if not ids or min(ids) < 0:
        parser.error(f'--ids: expected non-negative integers, got {args.ids!r}')
    return ids


class CrashRequests:
    """SIGUSR1 says `uav-flock kill` has named MAPs of this process in crash_dir: their nodes are to end.

    A SIGKILL takes every MAP of a process; this takes one, between callbacks, as abruptly: no last state or
    command, nothing flushed. Its writers and readers leave the graph with it, which is how world_sim tells
    that it is gone (as of a MAP on another host).
    """

    def __init__(self) -> None:
        self.pending = False
        signal.signal(signal.SIGUSR1, self._on_signal)

    def _on_signal(self, signum: int, frame: Optional[FrameType]) -> None:
        self.pending = True

    def take(self, nodes: list['AgentNode']) -> list['AgentNode']:
        """The nodes named in crash_dir, once per signal."""
        if not self.pending:
            return []
        self.pending = False
        return [n for n in nodes if n.crash_dir and (Path(n.crash_dir) / str(n.map_id)).exists()]


class RenewRequests:
    """SIGUSR2 asks the process to make its DDS participant anew at once, its MAPs going on where they were: what it
    does on its own when a connection carries nothing (recovery.stuck_midway), to be tried on a run by hand."""

    def __init__(self) -> None:
        self.pending = False
        signal.signal(signal.SIGUSR2, self._on_signal)

    def _on_signal(self, signum: int, frame: Optional[FrameType]) -> None:
        self.pending = True

    def take(self) -> Optional[str]:
        """Why to renew now, once per signal."""
        if not self.pending:
            return None
        self.pending = False
        return 'SIGUSR2'


def flush(nodes: list[AgentNode]) -> None:
    """What the MAPs said last reaches every reader that has not acknowledged it yet (the recorder may be repairing a
    lost datagram) before their writers go; a reader that died with its MAP is waited for no longer than FLUSH_S."""
    deadline = time.monotonic() + FLUSH_S
    for n in nodes:
        for pub in (n.state_pub, n.cmd_pub):
            pub.wait_for_all_acked(Duration(seconds=max(deadline - time.monotonic(), 0.0)))


class AgentProcess:
    """The MAPs of one process on one DDS participant (an rclpy context of their own): made at start, and
    made anew when a step stalls on a connection that carries nothing (recovery.stuck_at_start, stuck_midway)."""

    def __init__(self, ids: list[int], argv: list[str]) -> None:
        self.argv = argv
        self.renewed = 0
        self.context, self.executor, self.nodes = self.make(ids)

    def make(self, ids: list[int]) -> tuple[Context, Executor, list[AgentNode]]:
        context = Context()
        # No rclpy signal handlers: theirs shut the context down under a running callback, whose publish then
        # fails and is logged as a fatal callback error. The loop ends on the flag instead, between callbacks.
        rclpy.init(args=self.argv, context=context, signal_handler_options=SignalHandlerOptions.NO)
        try:
            nodes = [AgentNode(i, context) for i in ids]
        except BaseException:
            context.try_shutdown()
            raise
        executor = make_executor(context)
        for n in nodes:
            executor.add_node(n)
        return context, executor, nodes

    def stuck(self) -> Optional[str]:
        """Why the process stalls: its start (step 0 of a MAP on a silent connection, or no MAP that has seen the
        world, while no MAP of the process is past step 0), or a later step on a silent connection; None if it does
        not, or after RENEW_TIMES."""
        if self.renewed >= RENEW_TIMES:
            return None
        midway = next((n for n in self.nodes if n.stuck_midway()), None)
        if midway is not None:
            return f'step {midway.step}: neighbours matched but unheard after their readers were made anew {RENEW_MIDWAY_TRIES} times'
        if any(n.step > 0 for n in self.nodes):
            return None
        if any(n.stuck_at_start() for n in self.nodes):
            return f'step 0: neighbours matched but unheard {RENEW_AFTER_S:.0f} s'
        if any(n.unseen_at_start() for n in self.nodes):
            return f'start: no world_sim seen in {self.nodes[0].renew_unseen:g} s'
        return None

    def renew(self, why: str, stopping: Callable[[], bool]) -> None:
        """The same MAPs on a new participant, each going on where it was if any is past step 0 (AgentNode.carry);
        the old one goes once every new node hears world_sim's sensing writer (so world_sim, which drops a MAP of
        another host whose sensing no reader matches, never sees none), or RENEW_WAIT_S on (renew_unseen, if
        shorter, before any sensing)."""
        self.renewed += 1
        context, executor, nodes = self.context, self.executor, self.nodes
        nodes[0].get_logger().warning(f'{why}: the DDS participant of MAPs {[n.map_id for n in nodes]} made anew '
                                      f'({self.renewed} of {RENEW_TIMES})')
        self.context, self.executor, self.nodes = self.make([n.map_id for n in nodes])
        midway = any(n.step > 0 for n in nodes)
        if midway:
            for new, old in zip(self.nodes, nodes):
                new.carry(old)
        sensed = any(n.step >= 0 for n in nodes)  # else the world may not be there yet: wait no longer than it was
        deadline = time.monotonic() + (RENEW_WAIT_S if sensed else min(RENEW_WAIT_S, nodes[0].renew_unseen))
        while not stopping() and time.monotonic() < deadline and any(
                (midway or n.step < 0) and n.sensing_sub.get_publisher_count() == 0 for n in self.nodes):
            self.executor.spin_once(timeout_sec=0.1)
        flush(nodes)  # the recorder counts a MAP's step only once it holds every step before (recorder.StepProgress)
        executor.shutdown()
        for n in nodes:
            n.destroy_node()
        context.try_shutdown()

    def close(self) -> None:
        flush(self.nodes)
        # The executor first: the events executor holds the nodes' entities, and only once they are all
        # released is the DDS participant deleted (with its shared memory), even if this process then ends
        # by os._exit, past the interpreter's teardown.
        self.executor.shutdown()
        for n in self.nodes:
            n.summary()
            n.destroy_node()
        self.context.try_shutdown()


def main(argv: Optional[list[str]] = None) -> int:
    argv = sys.argv if argv is None else argv
    rest = checked_ros_args('uav_agent_node', argv)
    if rest is None:
        return 2
    ids = parse_ids(rest[1:])
    crashes = CrashRequests()  # before the nodes exist: a request that comes early waits for the loop
    renewals = RenewRequests()
    stop = StopSignals()
    try:
        process = AgentProcess(ids, argv)
    except PARAMETER_ERRORS as exc:  # a bad parameter value: the user's mistake
        print(f'uav_agent_node: error: {exc}', file=sys.stderr)
        return 2
    why = unheeded(argv, process.nodes[0]) if process.nodes else None
    if why:
        print(f'uav_agent_node: error: {why}', file=sys.stderr)
        process.close()
        return 2
    try:
        while process.nodes and not stop.received and not all(n.stopped for n in process.nodes):
            process.executor.spin_once(timeout_sec=0.5)
            for n in crashes.take(process.nodes):
                n.crash()
                process.executor.remove_node(n)
                n.destroy_node()
                process.nodes.remove(n)
            why = renewals.take() or process.stuck()
            if why:
                process.renew(why, lambda: stop.received)
    finally:
        code = 1 if any(n.stopped and not n.run_finished for n in process.nodes) else 0
        leave_after(code, 'uav_agent_node')  # processes.TEARDOWN_S
        process.close()
    return code


if __name__ == '__main__':
    sys.exit(main())
