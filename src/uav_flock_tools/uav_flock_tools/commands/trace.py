"""`uav-flock trace`: one run of a study flown again, saying what split its network and why a MAP moved."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .options import UsageError, id_list, non_negative_float, own_process, positive_float

SUMMARY = 'fly one run of a study again: what split its network, and why a MAP moved (nominal, filter, command)'


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('spec', help='a study spec (studies/*.yaml), or a study folder (its spec.yaml)')
    p.add_argument('run', help='the run: its key (the study\'s `key` column) or LAYOUT/SEED/KIND, say 19/0/drift:2')
    p.add_argument('--variant', help='the variant, when the spec flies the run under several')
    p.add_argument('--map', type=id_list, default=[], metavar='IDS',
                   help='MAPs to follow, a line each every --every s: 36, or 3,36, or 30-39 (default: none)')
    p.add_argument('--from', dest='t0', type=non_negative_float, default=0.0, help='start at this time, s (default: 0)')
    p.add_argument('--to', dest='t1', type=non_negative_float,
                   help='stop at this time, s (default: the end of the run)')
    p.add_argument('--every', type=positive_float, default=1.0, help='a line per MAP every this many s (default: 1)')


def handle(args: argparse.Namespace) -> int:
    from uav_agent.core import ablation

    from ..study import engine
    from ..study.spec import SpecError, load, runs
    from ..trace import Window, pick, trace
    path = Path(args.spec)
    if path.is_dir():
        path = path / 'spec.yaml'
        if not path.exists():
            raise UsageError(f'trace: {args.spec}: a folder with no spec.yaml (not a study folder)')
    try:
        grid = runs(load(path))
    except SpecError as exc:
        raise UsageError(f'trace: {exc}') from None
    try:
        run = pick(grid, args.run, args.variant)
    except ValueError as exc:
        raise UsageError(f'trace: {exc}') from None
    s = run.scenario()
    if any(i >= s.maps for i in args.map):
        raise UsageError(f'trace: --map: the run flies MAPs 0-{s.maps - 1}')
    if args.t1 is not None and args.t1 < args.t0:
        raise UsageError('trace: --to comes before --from')
    own_process('trace', [s.vehicle.model])
    off = f'; rules off: {", ".join(run.off)}' if run.off else ''
    print(f'trace: layout {run.layout}, seed {run.seed}, {run.kind}, variant {run.variant} (key {run.key}): '
          f'{s.maps} MAPs, {s.duration:g} s, vehicle {s.vehicle.model}, safety {s.flock.safety}{off}', flush=True)
    window = Window(tuple(args.map), args.t0, s.duration if args.t1 is None else args.t1, args.every)
    with ablation.switched_off(run.off):
        splits = trace(engine.flight(run, s, watch=True), window, sys.stdout)
    print(f'trace: {splits} split{"s" if splits != 1 else ""} from {window.t0:g} s to {window.t1:g} s')
    return 0
