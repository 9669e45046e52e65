"""A drifting cluster on random layouts, with the adaptation mechanisms of docs/dynamics.md taken out one by one.

Run: ./uav-flock exec python benchmarks/bench_dynamics_layouts.py [--layouts 20 --seeds 2 --speed 2 --factor 1.5
     --variants full,no swing,fresh keys,no transit,neither]
Layout n is layout n of `./uav-flock layouts --seed 0` (3 to 6 clusters); its cluster 0 drifts at --speed m/s
in a direction drawn per layout; N = ceil(factor x LB); default policies, online survey, 90 s batch runs.
Each variant runs on the same layouts and seeds, so the columns compare like with like:
  full           what ships
  no swing       a relay whose edge is swapped for one sharing a cluster flies along the tree, like any other
                 MAP changing role (demand.pivot never swings)
  fresh keys     every survey lays the roles' keys end to end afresh, not carried over (keys.carry)
  no transit     a MAP that changes role flies straight to it (en_route never routes)
  neither        carried keys and transit both taken out (relays still swing)
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Optional

import numpy as np

from uav_agent.core import demand, keys
from uav_flock_tools.layouts import draw, policy_sets
from uav_flock_tools.batch import BatchSimulator
from world_sim.core import layouts
from world_sim.core.scenario import Scenario
from world_sim.shipped import load_scenario

VARIANTS = ('full', 'no swing', 'fresh keys', 'no transit', 'neither')


def run(job: tuple[str, Scenario]) -> tuple[Optional[float], Optional[float]]:
    """(time-averaged R_c, fraction of time connected) after first convergence; (None, None) if never."""
    variant, s = job
    if variant in ('fresh keys', 'neither'):
        keys.carry = lambda old, shares: keys.fresh(keys.end_to_end(shares))
    if variant in ('no transit', 'neither'):
        demand.en_route = lambda *args: demand.NO_GOAL
    if variant == 'no swing':
        demand.pivot = lambda *args: None
    m = BatchSimulator(s).run().metrics
    ok = (m[:, 2] >= 0.95) & (m[:, 3] > 0)
    if not ok.any():
        return None, None
    first = int(np.argmax(ok))
    return float(m[first:, 2].mean()), float(np.mean(m[first:, 3] > 0))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument('--layouts', type=int, default=20, help='random layouts (default: 20)')
    ap.add_argument('--seeds', type=int, default=2, help='seeds per layout (default: 2)')
    ap.add_argument('--speed', type=float, default=2.0, help='drift speed of cluster 0, m/s (default: 2)')
    ap.add_argument('--factor', type=float, default=1.5, help='MAPs as a multiple of the floor LB (default: 1.5)')
    ap.add_argument('--variants', default=','.join(VARIANTS),
                    help=f'comma-separated, of: {", ".join(VARIANTS)} (default: all)')
    args = ap.parse_args()
    variants = [v.strip() for v in args.variants.split(',') if v.strip()]
    if not variants or any(v not in VARIANTS for v in variants):
        ap.error(f'--variants: choose from {", ".join(VARIANTS)}')
    if args.layouts < 1 or args.seeds < 1 or not args.speed >= 0 or not args.factor > 0:
        ap.error('--layouts and --seeds must be at least 1, --speed non-negative, --factor positive')
    paper = load_scenario('paper')
    flock = policy_sets(paper)['default']
    rng = np.random.default_rng(0)
    jobs = []
    for n, lay in enumerate(draw('paper', args.layouts, (3, 6), 0)):
        heading = rng.uniform(0, 2 * math.pi)
        v = (round(args.speed * math.cos(heading), 3), round(args.speed * math.sin(heading), 3))
        clusters = (dataclasses.replace(lay.clusters[0], velocity=v), *lay.clusters[1:])
        maps = math.ceil(args.factor * layouts.floor(lay).total)
        for seed in range(args.seeds):
            s = dataclasses.replace(lay, clusters=clusters, maps=maps, seed=seed, duration=90.0, flock=flock,
                                    survey='online')
            jobs += [(variant, s) for variant in variants]
    print(f'{len(jobs)} runs: {args.layouts} layouts x {args.seeds} seeds x {len(variants)} variants', flush=True)
    t0 = time.perf_counter()
    results: list[tuple[Optional[float], Optional[float]]] = []
    with ProcessPoolExecutor(max_workers=2, max_tasks_per_child=1) as pool:  # a fresh process per variant
        for i, r in enumerate(pool.map(run, jobs), 1):
            results.append(r)
            if i % 20 == 0 or i == len(jobs):
                print(f'  {i}/{len(jobs)} runs, {time.perf_counter() - t0:.0f} s', flush=True)
    print(f'\nCluster 0 drifting at {args.speed:g} m/s, N = ceil({args.factor:g} x LB):\n')
    print('| variant | runs converged | time-averaged R_c after convergence (mean) | time connected after it '
          '(mean, worst run) | runs connected ≥ 95 % of the time |')
    print('|---|---|---|---|---|')
    for variant in variants:
        mine = [r for (v, _), r in zip(jobs, results) if v == variant]
        ok = [r for r in mine if r[0] is not None]
        rc = [r[0] for r in ok]
        con = [r[1] for r in ok]
        print(f'| {variant} | {len(ok)}/{len(mine)} | {100 * np.mean(rc):.1f} % | {100 * np.mean(con):.1f} %, '
              f'{100 * min(con):.1f} % | {sum(c >= 0.95 for c in con)}/{len(mine)} |' if ok else
              f'| {variant} | 0/{len(mine)} | — | — | 0/{len(mine)} |')
    print(f'\n{time.perf_counter() - t0:.0f} s in all')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
