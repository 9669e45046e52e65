"""uav-flock command line (behind ./uav-flock): the dispatcher of the commands in `commands/`.

Running a scenario: `sim` (batch, in one process), `run` (the main job), `up` (distributed: world_sim and
the MAP agents as processes), `agents` (agents of another host joining an `up --listen`). Looking into a run:
`kill`, `echo`, `topics`, `report`, `view`, `replay`, `trace`. Measuring a layout or the method: `floor`, `layouts`,
`paper`, `study` (many runs on Dask).
"""
from __future__ import annotations

import argparse
import signal
import sys
from types import FrameType
from typing import Callable, Optional, Sequence

from .commands.options import EXIT_INTERRUPTED, EXIT_USAGE, Parser, UsageError


def build_parser() -> argparse.ArgumentParser:
    """Each command's parser, whose `--help` opens with the line `uav-flock --help` lists it with."""
    from .commands import COMMANDS, name
    parser = Parser(prog='uav-flock', description=__doc__)
    sub = parser.add_subparsers(dest='command', required=True, parser_class=Parser)
    for module in COMMANDS:
        summary = module.SUMMARY
        p = sub.add_parser(name(module), help=summary, description=summary[0].upper() + summary[1:] + '.')
        module.add_arguments(p)
        p.set_defaults(func=module.handle)
    return parser


def _main(argv: Optional[Sequence[str]]) -> int:
    try:
        args, extra = build_parser().parse_known_args(argv)
        if extra:  # the top-level parser would say it without naming the subcommand
            raise UsageError(f'{args.command}: unrecognized arguments: {" ".join(extra)} '
                             f'(see `uav-flock {args.command} --help`)')
        args.argv = list(sys.argv[1:] if argv is None else argv)
        func: Callable[[argparse.Namespace], int] = args.func
        return func(args)
    except UsageError as exc:
        print(f'uav-flock: error: {exc}', file=sys.stderr)
        return EXIT_USAGE
    except Exception as exc:
        # The scenario, or an option that overrides a key of it. The scenario loader (numpy, scipy) is imported
        # here, not before parsing: a mistyped option is said in half the time.
        from world_sim.core.scenario import ScenarioError
        if not isinstance(exc, ScenarioError):
            raise
        print(f'uav-flock: error: {args.command}: {exc}', file=sys.stderr)
        return EXIT_USAGE



RETRY_INTERRUPT_S = 0.05
# Commands whose stdout is what they make: when its reader leaves (`echo /metrics | head -3`) they are done. Every
# other command's records are its files: it goes on to the end with its stdout closed.
PRINTERS = ('echo', 'topics', 'trace')



def _interrupt(signum: int, frame: Optional[FrameType]) -> None:
    raise KeyboardInterrupt



def _unraisable(args: 'sys.UnraisableHookArgs') -> None:
    """An interrupt that landed where Python swallows exceptions (a weakref callback of an import) is raised again.

    Otherwise a Ctrl-C or `kill PID` at that moment would be lost and the command would carry on.
    """
    if args.exc_type is KeyboardInterrupt:
        signal.setitimer(signal.ITIMER_REAL, RETRY_INTERRUPT_S)  # SIGALRM: _interrupt, once out of the callback
        return
    sys.__unraisablehook__(args)



def install_interrupts() -> None:
    """`kill PID` stops a command as Ctrl-C does, so its clean-up (children stopped, partial records) runs too."""
    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGALRM, _interrupt)
    sys.unraisablehook = _unraisable



def main(argv: Optional[Sequence[str]] = None) -> int:
    # Only the standard library is imported above: Ctrl-C while numpy, rclpy and the rest load is caught here too.
    install_interrupts()
    from .outlast import Outlasting, standard_streams
    standard_streams()
    command = next((a for a in (sys.argv[1:] if argv is None else argv) if not a.startswith('-')), '')
    if command not in PRINTERS:
        # stdout and stderr alike: `sim ... 2>&1 | head -1` closes the progress bar's stream, not only the prints'
        sys.stdout = Outlasting(sys.stdout)  # type: ignore[assignment]
        sys.stderr = Outlasting(sys.stderr)  # type: ignore[assignment]
    try:
        return _main(argv)
    except KeyboardInterrupt:
        print('uav-flock: interrupted', file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # The reader of a printer's output left (`echo /metrics | head -3`): done, quietly, as `ros2 topic echo | head`.
        # What Python would still flush at exit goes nowhere instead of raising again.
        import os
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == '__main__':
    sys.exit(main())
