"""Users that move: each shipped dynamic scenario over several seeds, and the drift speed that loses a cluster.

Run: ./uav-flock exec python benchmarks/bench_dynamics.py [--seeds 5 --speeds 1,2,3,4,5,6,7,8 --out docs/figures]
[--vehicle multirotor|ideal]. Prints the tables of docs/results.md ("Users that move": the shipped multirotor, as the
scenario files say, and with --vehicle ideal the paper's vehicle) and writes coverage and Fiedler plots per scenario,
every seed drawn, with arrivals and departures marked. All runs are batch runs (the oracle the distributed
system equals byte for byte, tests/ros/test_moving_users_dds.py).
"""
from __future__ import annotations

import argparse
import dataclasses
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any, Optional

import numpy as np

from uav_flock_tools import plots
from uav_flock_tools.batch import BatchSimulator
from world_sim.core.crowd import events
from world_sim.core.scenario import Scenario
from world_sim.shipped import load_scenario

SCENARIOS = ('drift', 'arrival', 'dispersal')
COVERED = 0.95


def run(s: Scenario) -> dict[str, Any]:
    """One run: metrics and each drawn cluster's served fraction at every step."""
    sim = BatchSimulator(s)
    true = []
    while sim.world.k < s.steps:
        true.append(sim.world.true_coverage(sim.step()))
    true.append(sim.world.true_coverage(sim.step(integrate=False)))
    return {'metrics': sim.result().metrics, 'true': np.array(true)}


def figures(m: np.ndarray) -> dict[str, Optional[float]]:
    """Time-averaged R_c and the fraction of time connected after first convergence (R_c >= 95 %, lambda2 > 0)."""
    t, rc, lam = m[:, 1], m[:, 2], m[:, 3]
    ok = (rc >= COVERED) & (lam > 0)
    if not ok.any():
        return {'converged': None, 'rc': None, 'connected': None}
    first = int(np.argmax(ok))
    return {'converged': float(t[first]), 'rc': float(rc[first:].mean()), 'connected': float(np.mean(lam[first:] > 0))}


def arrival_time(s: Scenario, r: dict[str, Any]) -> Optional[float]:
    """Seconds from the last-arriving cluster's start to it being covered (>= 95 %) with the formation connected."""
    late = [k for k, c in enumerate(s.clusters) if c.start > 0]
    if not late:
        return None
    k = max(late, key=lambda j: s.clusters[j].start)
    m, cover = r['metrics'], r['true'][:, k]
    t = m[:, 1]
    ok = (t >= s.clusters[k].start) & (np.nan_to_num(cover) >= COVERED) & (m[:, 5] == 1)
    return float(t[np.argmax(ok)] - s.clusters[k].start) if ok.any() else None


def kept(r: dict[str, Any], k: int, window: float, dt: float) -> bool:
    """Cluster k stayed served: its coverage >= 95 % on average over the last `window` s, formation connected
    at least 90 % of that time."""
    n = int(round(window / dt))
    return bool(np.nanmean(r['true'][-n:, k]) >= COVERED and np.mean(r['metrics'][-n:, 3] > 0) >= 0.9)


def pct(v: Optional[float]) -> str:
    return '—' if v is None else f'{100 * v:.1f} %'


def secs(v: Optional[float]) -> str:
    return 'not reached' if v is None else f'{v:.1f} s'


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument('--seeds', type=int, default=5, help='seeds per scenario and speed (default: 5)')
    ap.add_argument('--speeds', default='1,2,3,4,5,6,7,8', help='drift speeds to sweep, m/s (default: 1..8)')
    ap.add_argument('--out', type=Path, default=Path('docs/figures'), help='folder for the plots')
    ap.add_argument('--vehicle', choices=('ideal', 'multirotor'), default='multirotor',
                    help="what the MAPs fly (default: multirotor, as the shipped scenarios say; ideal: the paper's)")
    args = ap.parse_args()
    if args.seeds < 1:
        ap.error('--seeds: must be at least 1')
    try:
        speeds = [float(v) for v in args.speeds.split(',')]
    except ValueError:
        ap.error(f'--speeds: expected numbers separated by commas, got {args.speeds!r}')
    shipped = {name: load_scenario(name).with_overrides(vehicle=args.vehicle) for name in SCENARIOS}
    tag, craft = ('', '') if args.vehicle == 'ideal' else (f'_{args.vehicle}', f', {args.vehicle}')
    jobs: list[tuple[str, float, int, Scenario]] = []
    for name, s in shipped.items():
        jobs += [(name, 0.0, seed, s.with_overrides(seed=seed)) for seed in range(args.seeds)]
    drift = shipped['drift']
    mover = next(k for k, c in enumerate(drift.clusters) if c.velocity != (0.0, 0.0))
    for v in speeds:
        clusters = tuple(dataclasses.replace(c, velocity=(v, 0.0)) if k == mover else c
                         for k, c in enumerate(drift.clusters))
        jobs += [('sweep', v, seed, dataclasses.replace(drift, clusters=clusters, seed=seed))
                 for seed in range(args.seeds)]
    print(f'{len(jobs)} runs on 2 processes, vehicle {args.vehicle}', flush=True)
    t0 = time.perf_counter()
    results = []
    with ProcessPoolExecutor(max_workers=2) as pool:
        for i, r in enumerate(pool.map(run, [j[3] for j in jobs]), 1):
            results.append(r)
            if i % 10 == 0 or i == len(jobs):
                print(f'  {i}/{len(jobs)} runs, {time.perf_counter() - t0:.0f} s', flush=True)

    print('\n| scenario | seeds converged | first convergence (median) | time-averaged R_c after it (min–max) '
          '| time connected after it (min–max) | arrival covered and bridged after (median, max) |')
    print('|---|---|---|---|---|---|')
    args.out.mkdir(parents=True, exist_ok=True)
    for name, s in shipped.items():
        mine = [r for j, r in zip(jobs, results) if j[0] == name]
        f = [figures(r['metrics']) for r in mine]
        ok = [x for x in f if x['converged'] is not None]
        arr = [arrival_time(s, r) for r in mine]
        arr_txt = '—'
        if any(c.start > 0 for c in s.clusters):
            done = [a for a in arr if a is not None]
            arr_txt = (f'{np.median(done):.1f} s, {max(done):.1f} s' if len(done) == len(arr)
                       else f'{len(done)}/{len(arr)} reached')
        if ok:
            rc = [x['rc'] for x in ok]
            con = [x['connected'] for x in ok]
            print(f'| {name} | {len(ok)}/{len(f)} | {np.median([x["converged"] for x in ok]):.1f} s | '
                  f'{pct(float(np.mean(rc)))} ({pct(min(rc))}–{pct(max(rc))}) | '
                  f'{pct(float(np.mean(con)))} ({pct(min(con))}–{pct(max(con))}) | {arr_txt} |')
        else:
            print(f'| {name} | 0/{len(f)} | — | — | — | {arr_txt} |')
        marks = events(s)
        plots.time_series([(f'seed {j[2]}', r['metrics'][:, 1], 100 * r['metrics'][:, 2])
                           for j, r in zip(jobs, results) if j[0] == name],
                          'coverage ratio R_c (%)', f'Coverage, {name} (90 MAPs{craft})',
                          args.out / f'dynamics_{name}{tag}_coverage.png',
                          marks)
        plots.fiedler_series([(f'seed {j[2]}', r['metrics'][:, 1], r['metrics'][:, 3])
                              for j, r in zip(jobs, results) if j[0] == name],
                             f'Connectivity, {name} (90 MAPs{craft})',
                             args.out / f'dynamics_{name}{tag}_fiedler.png', marks)

    print(f'\n| drift speed | seeds that keep the drifting cluster (last 30 s) | time-averaged R_c | time connected |')
    print('|---|---|---|---|')
    lost = None
    for v in speeds:
        mine = [r for j, r in zip(jobs, results) if j[0] == 'sweep' and j[1] == v]
        keep = sum(kept(r, mover, 30.0, drift.dt) for r in mine)
        f = [figures(r['metrics']) for r in mine]
        rc = [x['rc'] for x in f if x['rc'] is not None]
        con = [x['connected'] for x in f if x['connected'] is not None]
        print(f'| {v:g} m/s | {keep}/{len(mine)} | {pct(float(np.mean(rc))) if rc else "—"} | '
              f'{pct(float(np.mean(con))) if con else "—"} |')
        if lost is None and keep * 2 < len(mine):
            lost = v
    print(f'\nthe drifting cluster is lost (most seeds) from {lost:g} m/s' if lost is not None
          else '\nthe drifting cluster is kept at every speed swept')
    print(f'{time.perf_counter() - t0:.0f} s in all; plots in {args.out}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
