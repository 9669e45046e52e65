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


class Unheeded(ValueError):
    """A -p on the command line that the node did not take (unheeded)."""


def unheeded(argv: list[str], node: Node) -> Optional[str]:
    """Why a `-p NAME:=VALUE` of argv did not take, or None when each did: beside a --params-file that sets the
    same parameter for every node (`/**`), rcl keeps the file's value and drops the -p without a word."""
    import yaml
    words = argv[argv.index('--ros-args') + 1:] if '--ros-args' in argv else []
    for flag, text in zip(words, words[1:]):
        if flag not in ('-p', '--param') or ':=' not in text:
            continue
        name, value = text.split(':=', 1)
        name = name.rsplit(':', 1)[-1]
        if not node.has_parameter(name):
            continue
        try:
            wanted = yaml.safe_load(value)
        except yaml.YAMLError:
            wanted = value
        got = node.get_parameter(name).value
        numbers = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (wanted, got))
        if (float(wanted) != float(got)) if numbers else wanted != got:
            return (f'parameter {name}: -p {text} did not take: a --params-file sets it to {got!r}, and rcl keeps '
                    "the file's value; change it in the file instead")
    return None


def spun_node(program: str, factory: Callable[[], N], user_errors: tuple[type[Exception], ...],
              argv: Optional[list[str]] = None) -> tuple[Optional[N], Optional[Executor]]:
    """The node on its executor; a user mistake in its parameters is one line on stderr and (None, None)."""
    try:
        node = factory()
        why = unheeded(sys.argv if argv is None else argv, node) if isinstance(node, Node) else None
        if why:
            node.destroy_node()
            raise Unheeded(why)
    except (*PARAMETER_ERRORS, *user_errors, Unheeded) as exc:
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
    node, executor = spun_node(program, factory, user_errors, argv)
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
