"""`uav-flock layouts`: random cluster layouts as scenario files, with the floor LB of each."""
from __future__ import annotations

import argparse
from pathlib import Path

from .options import UsageError, count_range, default_out, make_folder, non_negative_int, positive_float, positive_int

SUMMARY = 'draw random cluster layouts as scenario files, with the MAP floor of each'


def add_arguments(p: argparse.ArgumentParser) -> None:
    from world_sim.core.airframes import AIRFRAMES
    p.add_argument('--count', type=positive_int, default=10, help='layouts to draw (default: 10)')
    p.add_argument('--clusters', type=count_range, default=(3, 6), help='clusters per layout, N or LOW-HIGH '
                                                                          '(default: 3-6)')
    p.add_argument('--seed', type=non_negative_int, default=0, help='seed of the draws (default: 0)')
    p.add_argument('--factor', type=positive_float, default=1.5,
                   help='MAPs per layout as a multiple of its floor LB, rounded up (default: 1.5)')
    p.add_argument('--duration', type=positive_float, default=90.0, help='simulated time in s (default: 90)')
    p.add_argument('--scenario', default='paper', help='scenario the layouts take everything else from '
                                                       '(default: paper; its policies are left out)')
    p.add_argument('--vehicle', choices=tuple(AIRFRAMES), default='multirotor',
                   help='what the layouts fly (docs/vehicle.md; default: multirotor, the shipped profile; ideal: '
                        "the paper's double integrator)")
    p.add_argument('--out', help='a new folder for the scenario files (default: runs/layouts-<time>)')


def handle(args: argparse.Namespace) -> int:
    from .. import layouts
    out = Path(args.out) if args.out else default_out('layouts')
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise UsageError(f'layouts: --out {out} exists and is not an empty folder; name a new one')
    drawn = layouts.draw(args.scenario, args.count, args.clusters, args.seed, args.vehicle)  # before any file: all or none
    return layouts.write(drawn, args.seed, args.factor, args.duration, make_folder(out, 'layouts: --out'))

