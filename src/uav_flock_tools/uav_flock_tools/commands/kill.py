"""`uav-flock kill`: MAPs of a running `up` killed as a crash would, by id or a random fraction."""
from __future__ import annotations

import argparse
from pathlib import Path

from .options import UsageError, fraction, int_list

SUMMARY = 'kill MAPs of a running `up` as a crash would: a MAP packed with others has its node ended inside its process, the others fly on'


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('--run', required=True, help='the run folder of `up`')
    p.add_argument('--ids', type=int_list, help='MAP ids to kill, e.g. 3,7')
    p.add_argument('--fraction', type=fraction, help='fraction of the live MAPs to kill, chosen at random')
    p.add_argument('--whole-processes', action='store_true',
                   help='SIGKILL the whole agent processes of the MAPs named, with every MAP they hold')


def handle(args: argparse.Namespace) -> int:
    from ..kill import kill
    if (args.ids is None) == (args.fraction is None):
        raise UsageError('kill: give exactly one of --ids or --fraction')
    try:
        killed, inside, whole = kill(Path(args.run), args.ids, args.fraction, args.whole_processes)
    except (FileNotFoundError, ValueError) as exc:
        raise UsageError(f'kill: {exc}') from None
    how = []
    if inside:
        how.append(f'their nodes ended inside process{"es" if len(inside) > 1 else ""} {inside}, '
                   f'whose other MAPs fly on')
    if whole:
        how.append(f'process{"es" if len(whole) > 1 else ""} {whole} SIGKILLed with every MAP '
                   f'{"they" if len(whole) > 1 else "it"} held')
    print(f'killed MAPs {killed} ({"; ".join(how)})')
    return 0

