"""`uav-flock run`: the main job, a scenario distributed and recorded, then the report of its bag."""
from __future__ import annotations

import argparse
from pathlib import Path

from . import report, sim, up
from .options import UsageError, add_scenario_options, add_view_option, default_out

SUMMARY = 'the main job: a scenario (the paper with 90 MAPs) distributed and recorded, with plots and a report of its bag'


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_scenario_options(p, grid=False, failures=False, vehicle='multirotor')
    p.add_argument('--batch', action='store_true', help='in one process with the batch simulator instead (seconds)')
    add_view_option(p)
    p.add_argument('--out', help='output folder (default: runs/run-<time>)')
    p.add_argument('--replace', action='store_true', help='replace the earlier run in --out (refused otherwise)')


def handle(args: argparse.Namespace) -> int:
    """The main job: a scenario (the paper's with 90 MAPs by default), distributed and recorded, then its report."""
    ns = argparse.Namespace(command='run', scenario=args.scenario, maps=args.maps, seed=args.seed,
                            duration=args.duration, fail_at=None, fail_fraction=None, vehicle=args.vehicle,
                            out=args.out or str(default_out('run')), replace=args.replace, argv=args.argv)
    if args.batch:
        if args.view is not None:
            raise UsageError('run: --view watches the distributed run; --batch has no topics to watch')
        ns.__dict__.update(maps=None if args.maps is None else [args.maps],
                           seed=None if args.seed is None else [args.seed], pictures=None)
        return sim.handle(ns)
    ns = up_options(ns, record=True, view=args.view)
    code = up.handle(ns)
    bag_path = Path(ns.out) / 'bag'
    if (bag_path / 'metadata.yaml').exists():
        code = report.handle(argparse.Namespace(bag=str(bag_path), out=None, replace=True)) or code
    return code


def up_options(ns: argparse.Namespace, **chosen: object) -> argparse.Namespace:
    """`up`'s options as its parser's defaults, then run's own (ns) and the chosen: an option `up` gains later is
    there with its default, where a hand-made list missed `--secure` and made `run` a traceback."""
    parser = argparse.ArgumentParser()
    up.add_arguments(parser)
    return argparse.Namespace(**{**vars(parser.parse_args([])), **vars(ns), **chosen})
