"""The executor every uav-flock process spins: rclpy's EventsExecutor where this rclpy has it.

The default executor rebuilds a wait set over all of a node's entities for every callback; a world node
with one subscription and one publisher per MAP then spends most of a step doing so. The events executor
dispatches each callback directly.
"""
from __future__ import annotations

import signal
import sys
from contextlib import contextmanager
from types import FrameType
from typing import Any, Callable, Iterator, Optional, TypeVar

import rclpy
from rclpy.context import Context
from rclpy.exceptions import ParameterException
from rclpy.executors import Executor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.subscription import Subscription

N = TypeVar('N', bound=Node)
# A parameter of the wrong type (`-p r:=abc` where r is a float) is the user's mistake in any node.
PARAMETER_ERRORS = (ParameterException, ValueError)


class StopSignals:
    """SIGINT and SIGTERM set a flag that the spin loop reads, so the process can end its run in order.

    An exception raised by a signal handler lands in whatever callback runs, and the events executor logs it
    as a fatal callback error. Pair with `rclpy.init(signal_handler_options=SignalHandlerOptions.NO)`.
    """

    def __init__(self) -> None:
        self.received = False
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._on_signal)

    def _on_signal(self, signum: int, frame: Optional[FrameType]) -> None:
        self.received = True

    def spin(self, executor: Executor) -> None:
        """Spin until SIGINT or SIGTERM: a node program's life between its start (started) and its end."""
        while not self.received:
            executor.spin_once(timeout_sec=0.1)


@contextmanager
def signals_deferred() -> Iterator[None]:
    """SIGINT and SIGTERM held back until the block ends, then handled as they would have been.

    A handler that raises (a command line's KeyboardInterrupt) half-way through an rclpy constructor
    leaves an object whose __del__ then prints rclpy's own traceback ("Exception ignored in
    Executor.__del__ ... no attribute '_sigint_gc'"). Build rclpy's context, nodes and executors in here.
    """
    caught: list[int] = []
    held = (signal.SIGINT, signal.SIGTERM)
    before = {sig: signal.signal(sig, lambda signum, frame: caught.append(signum)) for sig in held}
    try:
        yield
    finally:
        for sig, handler in before.items():
            signal.signal(sig, handler)
        if caught and callable(before[caught[0]]):
            before[caught[0]](caught[0], None)


def make_executor(context: Optional[Context] = None) -> Executor:
    try:
        from rclpy.experimental import EventsExecutor
    except ImportError:  # rclpy before Jazzy
        return SingleThreadedExecutor(context=context)
    return EventsExecutor(context=context)


def checked_ros_args(program: str, argv: list[str]) -> Optional[list[str]]:
    """argv without its ROS arguments, or None after one line on stderr when they are a user's mistake (a params
    file that is not there, a malformed remap): rcl would raise RCLInvalidROSArgsError with its C source lines."""
    from pathlib import Path
    for i, word in enumerate(argv[:-1]):
        if word == '--params-file' and not Path(argv[i + 1]).is_file():
            print(f'{program}: error: --params-file {argv[i + 1]}: no such file', file=sys.stderr)
            return None
    try:
        return rclpy.utilities.remove_ros_args(argv)
    except rclpy._rclpy_pybind11.RCLInvalidROSArgsError as exc:  # noqa: SLF001 -- rclpy exports it nowhere else
        print(f'{program}: error: {str(exc).split(", at ")[0]}', file=sys.stderr)
        return None


def spun_node(program: str, factory: Callable[[], N], user_errors: tuple[type[Exception], ...]
              ) -> tuple[Optional[N], Optional[Executor]]:
    """The node on its executor; a user mistake in its parameters is one line on stderr and (None, None)."""
    try:
        node = factory()
    except (*PARAMETER_ERRORS, *user_errors) as exc:
        print(f'{program}: error: {exc}', file=sys.stderr)
        rclpy.try_shutdown()
        return None, None
    executor = make_executor()
    executor.add_node(node)
    return node, executor


def started(program: str, factory: Callable[[], N], user_errors: tuple[type[Exception], ...],
            argv: Optional[list[str]] = None) -> tuple[N, Executor, 'StopSignals']:
    """A node program's start, the same for each: its ROS arguments checked, rclpy initialised with SIGINT and
    SIGTERM left to StopSignals, the node on its executor. A user's mistake: one line on stderr, exit 2."""
    argv = sys.argv if argv is None else argv
    if checked_ros_args(program, argv) is None:
        raise SystemExit(2)
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    stop = StopSignals()
    node, executor = spun_node(program, factory, user_errors)
    if node is None or executor is None:
        raise SystemExit(2)
    return node, executor, stop


def take_waiting(sub: Subscription, handle: Callable[[Any], bool], raw: Optional[bool] = None) -> int:
    """Take what sits in a subscription's reader, as the executor itself would (rclpy's own take call),
    whether or not an event announced it; handle(message) returns False to stop. Returns how many."""
    count = 0
    with sub.handle:
        while (got := sub.handle.take_message(sub.msg_type, sub.raw if raw is None else raw)) is not None:
            count += 1
            if not handle(got[0]):
                break
    return count
