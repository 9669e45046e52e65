"""`uav-flock trace`: a run flown again, saying what split its network and why a MAP moved."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .options import UsageError, id_list, non_negative_float, own_process, positive_float

SUMMARY = 'fly a run again (a study\'s row, or a run folder): what split its network, and why a MAP moved'
RUN_SCENARIO = 'scenario.yaml'  # what a run folder of `sim` or `up` keeps of the scenario it flew, to fly it again


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('source', metavar='SPEC|RUN_FOLDER',
                   help='a study spec (studies/*.yaml) or study folder (its spec.yaml), or the run folder of a `sim` '
                        'or lockstep `up` (its scenario.yaml)')
    p.add_argument('run', nargs='?',
                   help='of a study: the run, its key (the `key` column) or LAYOUT/SEED/KIND, say 19/0/drift:2')
    p.add_argument('--variant', help='of a study: the variant, when the spec flies the run under several')
    p.add_argument('--map', type=id_list, default=[], metavar='IDS',
                   help='MAPs to follow, a line each every --every s: 36, or 3,36, or 30-39 (default: none)')
    p.add_argument('--from', dest='t0', type=non_negative_float, default=0.0, help='start at this time, s (default: 0)')
    p.add_argument('--to', dest='t1', type=non_negative_float,
                   help='stop at this time, s (default: the end of the run)')
    p.add_argument('--every', type=positive_float, default=1.0, help='a line per MAP every this many s (default: 1)')


def handle(args: argparse.Namespace) -> int:
    from uav_agent.core import ablation

    from ..batch import BatchSimulator
    from ..study import engine
    from ..study.spec import SpecError, load, runs
    from ..trace import Window, pick, summary, trace
    path = Path(args.source)
    off: tuple[str, ...] = ()
    if path.is_dir() and (path / RUN_SCENARIO).exists() and not (path / 'spec.yaml').exists():
        if args.run is not None or args.variant is not None:
            raise UsageError(f'trace: {path} is a run folder: it names one run, so no RUN or --variant')
        from .. import simrun
        s = simrun.load_scenario(str(path / RUN_SCENARIO))
        said = f'trace: {path}: '
        study_run = None
    else:
        if path.is_dir():
            path = path / 'spec.yaml'
            if not path.exists():
                raise UsageError(f'trace: {args.source}: a folder with neither spec.yaml (a study) nor '
                                 f'{RUN_SCENARIO} (a run of sim or up)')
        if args.run is None:
            raise UsageError('trace: a study names many runs: say which (its key, or LAYOUT/SEED/KIND)')
        try:
            grid = runs(load(path))
        except SpecError as exc:
            raise UsageError(f'trace: {exc}') from None
        try:
            run = pick(grid, args.run, args.variant)
        except ValueError as exc:
            raise UsageError(f'trace: {exc}') from None
        s, off = run.scenario(), run.off
        said = f'trace: layout {run.layout}, seed {run.seed}, {run.kind}, variant {run.variant} (key {run.key}): '
        study_run = run
    if any(i >= s.maps for i in args.map):
        raise UsageError(f'trace: --map: the run flies MAPs 0-{s.maps - 1}')
    if args.t1 is not None and args.t1 < args.t0:
        raise UsageError('trace: --to comes before --from')
    own_process('trace', [s.vehicle.model])
    rules = f'; rules off: {", ".join(off)}' if off else ''
    print(f'{said}{s.maps} MAPs, {s.duration:g} s, vehicle {s.vehicle.model}, safety {s.flock.safety}{rules}',
          flush=True)
    window = Window(tuple(args.map), args.t0, s.duration if args.t1 is None else args.t1, args.every)
    with ablation.switched_off(off):
        flight = (engine.flight(study_run, s, watch=True) if study_run is not None
                  else BatchSimulator(s, watch=True).flight())
        traced = trace(flight, window, sys.stdout)
    print('\n'.join(summary(traced, window)), flush=True)
    return 0
