"""Success of each policy set on random cluster layouts, at MAP counts scaled to each layout's floor LB.

Run: ./uav-flock exec python benchmarks/bench_layouts.py [--layouts 50 --seeds 2 --factors 1.2,1.5,2.0]
A run succeeds when it ends covered (mean R_c >= 95 %) and connected (lambda2 > 0 at every step) over its
last 10 s (world_sim.core.outcome). Layouts are drawn as `./uav-flock layouts` draws them.
"""
from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import replace
from typing import Any

import numpy as np

from uav_agent.core.params import POLICY_VALUES, FlockParams
from world_sim.batch import BatchSimulator
from world_sim.core import layouts, outcome
from world_sim.core.scenario import Scenario
from world_sim.scenarios import load_scenario

def policy_sets(paper: Scenario) -> dict[str, dict[str, Any]]:
    """The policy values of each set: what a scenario without `policies` runs, and paper.yaml's."""
    defaults, ours = FlockParams(), paper.flock
    return {'default': {k: getattr(defaults, k) for k in POLICY_VALUES},
            'paper': {k: getattr(ours, k) for k in POLICY_VALUES},
            'paper+share': {**{k: getattr(ours, k) for k in POLICY_VALUES}, 'edge_choice': 'share'}}


def one_run(job: tuple[str, int, float, int, Scenario]) -> dict[str, Any]:
    policy, layout, factor, lb, s = job
    t0 = time.perf_counter()
    result = BatchSimulator(s).run()
    o = outcome.judge(s, result.metrics, result.trajectory)
    fl = layouts.floor(s)
    return {'policy': policy, 'layout': layout, 'factor': factor, 'seed': s.seed, 'maps': s.maps, 'lb': lb,
            'k': len(s.clusters), 'outcome': o, 'floor': fl, 'wall': time.perf_counter() - t0}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument('--layouts', type=int, default=50)
    ap.add_argument('--seeds', type=int, default=2)
    ap.add_argument('--factors', default='1.2,1.5,2.0')
    ap.add_argument('--policies', default='default,paper')
    ap.add_argument('--duration', type=float, default=90.0)
    ap.add_argument('--layout-seed', type=int, default=0, help='seed of the layout draws')
    ap.add_argument('--workers', type=int, default=os.cpu_count() or 1)
    args = ap.parse_args()
    paper = load_scenario('paper')
    factors = [float(f) for f in args.factors.split(',')]
    policies = args.policies.split(',')
    rng = np.random.default_rng(args.layout_seed)
    drawn = [layouts.draw(paper, layouts.LayoutSpec(), rng) for _ in range(args.layouts)]
    jobs = []
    sets = policy_sets(paper)
    unknown = [p for p in policies if p not in sets]
    if unknown:
        ap.error(f'--policies: unknown set {unknown[0]!r} (known: {", ".join(sets)})')
    for policy in policies:
        flock = replace(paper.flock, **sets[policy])
        for li, lay in enumerate(drawn):
            lb = layouts.floor(lay).total
            for f in factors:
                for seed in range(args.seeds):
                    s = replace(lay, maps=math.ceil(f * lb), seed=seed, duration=args.duration, flock=flock)
                    jobs.append((policy, li, f, lb, s))
    print(f'{len(jobs)} runs: {args.layouts} layouts x {len(factors)} factors x {args.seeds} seeds x '
          f'{len(policies)} policy sets, {args.duration:g} s each, on {args.workers} workers', flush=True)
    rows: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.workers, initializer=signal.signal, initargs=(signal.SIGINT, signal.SIG_IGN)) as pool:
        futures = [pool.submit(one_run, j) for j in jobs]
        try:
            for n, fut in enumerate(as_completed(futures), 1):
                rows.append(fut.result())
                if n % 10 == 0 or n == len(jobs):
                    el = time.perf_counter() - t0
                    print(f'  {n}/{len(jobs)} runs, {el:.0f} s, ~{el / n * (len(jobs) - n):.0f} s left', flush=True)
        except KeyboardInterrupt:
            pool.shutdown(wait=False, cancel_futures=True)
            print(f'interrupted: tables from the {len(rows)} runs finished', file=sys.stderr)
    report(rows, policies, factors)
    return 0


def report(rows: list[dict[str, Any]], policies: list[str], factors: list[float]) -> None:
    for policy in policies:
        mine = [r for r in rows if r['policy'] == policy]
        if not mine:
            continue
        print(f'\n## policy set: {policy}\n')
        print('| N / LB | runs | success | median t to success (s) | final R_c % | connected | '
              'cluster MAPs / floor (min) | edge MAPs / floor (min) | astray | M0 at end |')
        print('|---|---|---|---|---|---|---|---|---|---|')
        for f in factors:
            rs = [r for r in mine if r['factor'] == f]
            if not rs:
                continue
            ok = [r for r in rs if r['outcome'].success]
            times = [r['outcome'].time_to_success for r in ok]
            cl = [min(n / max(d, 1) for n, d in zip(r['outcome'].per_cluster, r['floor'].per_cluster)) for r in rs]
            ed = [min((n / d for n, d in zip(r['outcome'].per_edge, r['floor'].per_edge) if d > 0), default=1.0)
                  for r in rs]
            print(f'| {f:g} | {len(rs)} | {100 * len(ok) / len(rs):.0f} % | '
                  f'{np.median(times) if times else float("nan"):.1f} | '
                  f'{100 * np.mean([r["outcome"].final_coverage for r in rs]):.1f} | '
                  f'{100 * np.mean([r["outcome"].connected_tail for r in rs]):.0f} % | '
                  f'{np.median(cl):.2f} | {np.median(ed):.2f} | '
                  f'{np.mean([r["outcome"].astray for r in rs]):.1f} | {np.mean([r["outcome"].in_m0 for r in rs]):.1f} |')
        print('\nsuccess by K (all factors):', ', '.join(
            f'K={k}: {100 * np.mean([r["outcome"].success for r in mine if r["k"] == k]):.0f} % '
            f'({sum(r["k"] == k for r in mine)})' for k in sorted({r['k'] for r in mine})))
        by_f_k = {}
        for r in mine:
            by_f_k.setdefault((r['factor'], r['k']), []).append(r['outcome'].success)
        print('success by N/LB and K:', '; '.join(f'{f:g}xLB K={k}: {100 * np.mean(v):.0f} %'
                                                 for (f, k), v in sorted(by_f_k.items())))
        print(f'wall per run: {np.mean([r["wall"] for r in mine]):.1f} s')


if __name__ == '__main__':
    sys.exit(main())
