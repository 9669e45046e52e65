"""Wall time of the batch simulator: the issue's reference sizes and how time grows with the MAP count.

Run: ./uav-flock exec python benchmarks/bench_sim.py
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time

import numpy as np

from uav_flock_tools.simrun import load_scenario
from uav_flock_tools.batch import BatchSimulator
from world_sim.core.scenario import Cluster, Scenario


def with_users(s: Scenario, total: int) -> Scenario:
    per = total // len(s.clusters)
    return dataclasses.replace(s, clusters=tuple(Cluster(c.center, c.spread, per) for c in s.clusters))


def timed(s: Scenario, steps: int, repeat: int = 3) -> float:
    """Best of repeat: wall seconds for steps steps (set-up excluded)."""
    best = np.inf
    for _ in range(repeat):
        sim = BatchSimulator(s)
        t0 = time.perf_counter()
        for _ in range(steps):
            sim.step()
        best = min(best, time.perf_counter() - t0)
    return best


def command_line(repeat: int = 3) -> None:
    """What a user waits for: `sim --maps 100 --duration 40` whole (start-up, simulation, records, PNGs and
    formation.gif), beside the simulation alone, best of repeat each."""
    import subprocess
    import tempfile
    s = load_scenario('paper').with_overrides(maps=100, duration=40.0)
    alone = min(timed_run(s) for _ in range(repeat))
    whole = np.inf
    for _ in range(repeat):
        with tempfile.TemporaryDirectory() as out:
            t0 = time.perf_counter()
            subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'sim', '--maps', '100', '--duration', '40',
                            '--out', out, '--replace'], check=True, capture_output=True)
            whole = min(whole, time.perf_counter() - t0)
    print(f'`sim --maps 100 --duration 40` with its pictures: {whole:.2f} s; the simulation alone: {alone:.2f} s '
          f'(target: whole < 3 s)', flush=True)


def timed_run(s: Scenario) -> float:
    t0 = time.perf_counter()
    BatchSimulator(s).run()
    return time.perf_counter() - t0


def main() -> int:
    argparse.ArgumentParser(prog='bench_sim', description=__doc__.split('\n')[0]).parse_args()  # no options
    base = load_scenario('paper')
    ref = timed(with_users(base.with_overrides(maps=100), 2000), 300)
    print(f'100 MAPs x 2000 MSDs x 300 steps: {ref:.3f} s  (target <= 1 s)', flush=True)
    big = timed(with_users(base.with_overrides(maps=500), 10000), 300, repeat=1)
    print(f'500 MAPs x 10000 MSDs x 300 steps: {big:.3f} s', flush=True)
    command_line()
    print('growth with MAP count (2000 MSDs, 300 steps):')
    print('  MAPs   wall s   ratio to 100 MAPs')
    for n in (50, 100, 200, 400, 800):
        t = ref if n == 100 else timed(with_users(base.with_overrides(maps=n), 2000), 300, repeat=1 if n > 200 else 3)
        print(f'  {n:4d}   {t:6.3f}   {t / ref:5.2f}', flush=True)
    return 0


if __name__ == '__main__':
    try:
        sys.exit(main())
    except KeyboardInterrupt:
        print('bench_sim: interrupted', file=sys.stderr)
        sys.exit(130)
