"""`uav-flock floor`: the least MAPs a scenario's layout needs, LB (docs/allocation.md)."""
from __future__ import annotations

import argparse

from .options import SCENARIO_HELP

SUMMARY = "the floor LB of a scenario's layout: the MAPs no method can do without"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('--scenario', default='paper', help=SCENARIO_HELP)


def handle(args: argparse.Namespace) -> int:
    from world_sim.core import layouts

    from .. import simrun
    s = simrun.load_scenario(args.scenario)
    floor = layouts.floor(s)
    print(f'{s.name}: LB = {floor.total} MAPs ({sum(floor.per_cluster)} to cover the clusters, '
          f'{sum(floor.per_edge)} to relay along the tree; the scenario flies {s.maps})')
    for k, n in enumerate(floor.per_cluster):
        print(f'  cluster {k}: {n}')
    for (a, b), n in zip(floor.edges, floor.per_edge):
        print(f'  edge {a}-{b}: {n}')
    return 0

