"""`uav-flock report`: plots, an animation, scene.mcap and a summary table from a run's bag."""
from __future__ import annotations

import argparse
from pathlib import Path

from .options import BAG_HELP, UsageError, make_folder

SUMMARY = "plots and a summary table from a run's bag (ours or ros2 bag record's)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('bag', help=BAG_HELP)
    p.add_argument('--out', help='output folder (default: RUN/report next to the bag)')
    p.add_argument('--replace', action='store_true', help='write over an earlier report in that folder (refused otherwise)')


def handle(args: argparse.Namespace) -> int:
    from .. import bag, report
    try:
        path = bag.find_bag(Path(args.bag))
        out = Path(args.out) if args.out else (path.parent / 'report' if path.name == 'bag' else path / 'report')
        if out.is_dir() and any(out.iterdir()) and not args.replace:
            raise UsageError(f'report: {out} holds a report already; pass --replace to write it anew, '
                             'or --out for another folder')
        make_folder(out, 'report: --out')
        summary, files = report.report(path, out)
    except bag.BagError as exc:
        raise UsageError(f'report: {exc}') from None
    print(report.summary_table(summary))
    print(f'{len(files)} files in {out}')
    return 0

