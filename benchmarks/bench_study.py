"""A study's throughput on a local Dask cluster against a plain process pool, the same runs, in one invocation.

Run: ./uav-flock exec python benchmarks/bench_study.py [--spec studies/smoke.yaml --workers 2 --repeat 2]
Both execute every run of the spec with the same function (study.engine.execute), one process a worker; the
study also starts its cluster, writes each row as it finishes and gathers the table. Prints runs per minute.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from uav_flock_tools.study import engine
from uav_flock_tools.study.spec import load, runs


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument('--spec', default=str(Path(__file__).resolve().parents[1] / 'studies' / 'smoke.yaml'))
    ap.add_argument('--workers', type=int, default=2)
    ap.add_argument('--repeat', type=int, default=2, help='each way, alternating (default: 2)')
    args = ap.parse_args()
    grid = runs(load(Path(args.spec)))
    pool, study = [], []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        with ProcessPoolExecutor(max_workers=args.workers) as ex:
            rows = list(ex.map(engine.execute, grid))
        pool.append(time.perf_counter() - t0)
        assert all(r['error'] is None for r in rows)
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            engine.study(grid, Path(tmp), workers=args.workers)
            study.append(time.perf_counter() - t0)
    best_pool, best_study = min(pool), min(study)
    print(f'{len(grid)} runs of {args.spec}, {args.workers} workers, best of {args.repeat}:')
    print(f'  process pool: {best_pool:.1f} s, {60 * len(grid) / best_pool:.1f} runs/min')
    print(f'  study (Dask LocalCluster, rows written as they finish): {best_study:.1f} s, '
          f'{60 * len(grid) / best_study:.1f} runs/min ({best_pool / best_study:.2f} x the pool\'s throughput)')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
