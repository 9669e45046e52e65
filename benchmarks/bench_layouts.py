"""Success of each policy set on random cluster layouts, at MAP counts scaled to each layout's floor LB.

Run: ./uav-flock exec python benchmarks/bench_layouts.py [--layouts 50 --seeds 2 --factors 1.2,1.5,2.0]
A run succeeds when it ends covered (mean R_c >= 95 %) and connected (lambda2 > 0 at every step) over its
last 10 s (world_sim.core.outcome). Layout n is layout-<n>.yaml of `./uav-flock layouts --seed S`.
"""
from __future__ import annotations

import argparse
import sys
import time

from uav_flock_tools import layouts
from world_sim.shipped import load_scenario


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument('--layouts', type=int, default=50, help='layouts to draw (default: 50)')
    ap.add_argument('--seeds', type=int, default=2, help='seeds per layout and MAP count (default: 2)')
    ap.add_argument('--factors', default='1.2,1.5,2.0', help='MAP counts as multiples of LB (default: 1.2,1.5,2.0)')
    ap.add_argument('--policies', default='default,paper', help='policy sets: default, paper, paper+share')
    ap.add_argument('--duration', type=float, default=90.0, help='simulated s per run (default: 90)')
    ap.add_argument('--layout-seed', type=int, default=0, help='seed of the layout draws (default: 0)')
    args = ap.parse_args()
    paper = load_scenario('paper')
    factors = [float(f) for f in args.factors.split(',')]
    policies = args.policies.split(',')
    known = layouts.policy_sets(paper)
    if any(p not in known for p in policies):
        ap.error(f'--policies: known sets are {", ".join(known)}')
    total = args.layouts * len(factors) * args.seeds * len(policies)
    print(f'{total} runs: {args.layouts} layouts x {len(factors)} factors x {args.seeds} seeds x '
          f'{len(policies)} policy sets, {args.duration:g} s each', flush=True)
    t0 = time.perf_counter()

    def progress(done: int, total: int) -> None:
        if done % 20 == 0 or done == total:
            el = time.perf_counter() - t0
            print(f'  {done}/{total} runs, {el:.0f} s, about {el / done * (total - done):.0f} s left', flush=True)

    try:
        ended = layouts.evaluate(paper, args.layouts, args.seeds, factors, policies, args.duration,
                                 args.layout_seed, progress)
    except KeyboardInterrupt:
        print('interrupted', file=sys.stderr)
        return 130
    for policy in policies:
        print(f'\n### Policy set `{policy}`\n')
        print('\n'.join(layouts.table(ended, policy, factors)))
    print(f'\n{len(ended)} runs in {time.perf_counter() - t0:.0f} s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
