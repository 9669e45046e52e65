"""`uav-flock agents`: agent processes on this host that join an `up --listen` on another host."""
from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from .options import (AGENTS_PER_PROCESS_HELP, UsageError, auto_agents_per_process, default_out, host_keys, id_list,
                      positive_float, positive_int, run_folder)

RUN_INFO_TIMEOUT_S = 60.0  # agents --join: how long a run's /run_info is waited for (three tries of 20 s)


SUMMARY = 'agent processes on this host that join a run of `up --listen` on another'


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('--join', required=True, metavar='HOST:PORT', help='the address `up --listen` printed')
    p.add_argument('--ids', type=id_list, required=True, help='MAP ids to run here, e.g. 30-89')
    p.add_argument('--agents-per-process', type=positive_int, metavar='K', help=AGENTS_PER_PROCESS_HELP)
    p.add_argument('--timeout', type=positive_float, default=RUN_INFO_TIMEOUT_S,
                   help=f'wait this long for the run to answer (s, default: {RUN_INFO_TIMEOUT_S:g})')
    p.add_argument('--secure', type=Path, metavar='KEYS/HOST',
                   help='this host\'s folder of `uav-flock keys`, for a run of `up --secure` (docs/multihost.md)')
    p.add_argument('--out', help='folder for this host\'s logs and pids (default: runs/agents-<time>)')
    p.add_argument('--replace', action='store_true', help='replace an earlier folder in --out (refused otherwise)')


def handle(args: argparse.Namespace) -> int:
    """Agent processes on this host that join a run listening on another (`up --listen`)."""
    from .. import join, secure
    try:
        join.parse_address(args.join)
    except join.JoinError as exc:
        raise UsageError(f'agents: {exc}') from None
    keys = host_keys('agents', args.secure)
    out = run_folder(Path(args.out) if args.out else default_out('agents'), 'agents: --out', args.replace)
    try:
        return join.join(args.join, args.ids, out.resolve(),
                         args.agents_per_process or auto_agents_per_process(len(args.ids), secure=keys is not None),
                         args.timeout, keys)
    except join.JoinError as exc:
        shutil.rmtree(out / secure.FOLDER, ignore_errors=True)  # nothing joined: leave nothing behind
        if out.is_dir() and not any(out.iterdir()):
            out.rmdir()
        raise UsageError(f'agents: {exc}') from None

