"""The paper's layout on the shipped multirotor beside the paper's ideal vehicle, the radio of docs/links.md flown
again on the multirotor, and what the vehicle costs the batch simulator (docs/vehicle.md).

Run: ./uav-flock exec python benchmarks/bench_vehicle.py [--seeds 5] [--cost-only | --no-cost]
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import time
from typing import Any, Callable, Iterator

import numpy as np

from uav_agent.core import envelope
from uav_agent.core.links import Links
from uav_flock_tools.batch import BatchSimulator
from uav_flock_tools.simrun import load_scenario
from world_sim.core import outcome, physics, records, vehicle
from world_sim.core.airframes.multirotor import Multirotor
from world_sim.core.scenario import Scenario


def flown(s: Scenario) -> dict[str, Any]:
    """One run's figures: time to success (and / T* on a multirotor), share of time connected after it, the
    least distance, the envelope as the trajectory shows it, mean power and energy."""
    r = BatchSimulator(s).run()
    m = r.metrics
    first = outcome.time_to_success(m)
    after = m[:, 1] >= first if np.isfinite(first) else np.zeros(len(m), bool)
    speed, accel = outcome.flown(r.trajectory, s.dt)
    least = records.vehicle_column(m, 'min_distance')
    if least is None:  # the ideal vehicle records none: from its trajectory
        cols = records.columns(r.trajectory)
        least = np.array([physics.least_distance(np.column_stack([cols['x'], cols['y'], cols['z']])[cols['step'] == k])
                          for k in np.unique(cols['step'])])
    power = records.vehicle_column(m, 'power')
    return {'first': first, 't_star': outcome.t_star(dataclasses.replace(s, vehicle=vehicle.MULTIROTOR), r.users.centroids),
            'connected': float((m[after, 3] > 0).mean()) if after.any() else float('nan'),
            'least': float(np.nanmin(least)), 'speed': speed, 'accel': accel,
            'power': float(power.mean()) if power is not None else float('nan'),
            'energy': float(records.vehicle_column(m, 'energy')[-1]) if power is not None else float('nan')}


def table(label: str, rows: list[dict[str, Any]]) -> str:
    first = np.array([r['first'] for r in rows])
    ok = np.isfinite(first)
    ratio = first / np.array([r['t_star'] for r in rows])
    return (f"| {label} | {ok.sum()}/{len(rows)} | {np.median(first):.1f} | {np.median(ratio):.2f} (worst {ratio.max():.2f}) | "
            f"{100 * np.nanmean([r['connected'] for r in rows]):.1f} % | {min(r['least'] for r in rows):.2f} | "
            f"{max(r['speed'] for r in rows):.1f} | {max(r['accel'] for r in rows):.1f} | "
            + (f"{np.mean([r['power'] for r in rows]):.1f} | {np.mean([r['energy'] for r in rows]) / 1e3:.1f} |"
               if np.isfinite(rows[0]['power']) else '– | – |'))


HEAD = ('| vehicle | success | time to success, median (s) | / T*: median | connected after success | least distance (m) '
        '| top speed (m/s) | top acceleration (m/s²) | mean power (W) | energy (kJ) |\n|---|---|---|---|---|---|---|---|---|---|')


# What the vehicle adds to a step, wherever it is called from (world side: release, integration, GNSS, wind,
# traffic receiver, records; agent side: the envelope's rules). Timed where the code calls it, outermost only.
OWN = {Multirotor: ('release', 'traffic', 'estimate', 'power', 'step'),
       physics: ('least_distance',), envelope: ('capped', 'spring', 'keep_apart', 'governor', 'command')}


@contextlib.contextmanager
def timed_own() -> Iterator[dict[str, float]]:
    """Each of OWN timed while inside; flocking_within counted less eq. 9's terms, which the ideal vehicle computes."""
    spent: dict[str, float] = {}
    inside = [0]
    saved = [(owner, name, getattr(owner, name)) for owner, names in OWN.items() for name in names]
    flocking_within = envelope.flocking_within

    def clocked(f: Callable[..., Any], label: str) -> Callable[..., Any]:
        @functools.wraps(f)
        def g(*a: Any, **k: Any) -> Any:
            if inside[0]:
                return f(*a, **k)
            inside[0] += 1
            t0 = time.perf_counter()
            try:
                return f(*a, **k)
            finally:
                spent[label] = spent.get(label, 0.0) + time.perf_counter() - t0
                inside[0] -= 1
        return g

    def within(*a: Any, **k: Any) -> Any:  # its own work: the lead and the scaling, not the terms it calls
        terms = a[0]
        clock = [0.0]

        def counted(*b: Any, **c: Any) -> Any:
            t1 = time.perf_counter()
            try:
                return terms(*b, **c)
            finally:
                clock[0] += time.perf_counter() - t1
        t0 = time.perf_counter()
        out = flocking_within(counted, *a[1:], **k)
        spent['flocking_within'] = spent.get('flocking_within', 0.0) + time.perf_counter() - t0 - clock[0]
        return out
    try:
        for owner, name, f in saved:
            setattr(owner, name, clocked(f, name))
        envelope.flocking_within = within
        yield spent
    finally:
        for owner, name, f in saved:
            setattr(owner, name, f)
        envelope.flocking_within = flocking_within


def cost(maps: int, steps: int, repeats: int = 3) -> str:
    """Wall time of `steps` steps at `maps` MAPs on each vehicle, A B A B, best of two each; then the multirotor's
    run `repeats` times more with the vehicle's own functions timed (OWN) against the rest of that run: the median
    run's ratio (one run's own time against its own rest, so the machine's speed drifting between runs cancels)."""
    base = load_scenario('paper').with_overrides(maps=maps, duration=steps * 0.1)
    spread = dataclasses.replace(base, release_half_width=max(base.release_half_width, 4.0 * np.sqrt(maps)))
    times: dict[str, list[float]] = {'ideal': [], 'multirotor': []}
    for _ in range(2):
        for name, v in (('ideal', vehicle.IDEAL), ('multirotor', vehicle.MULTIROTOR)):
            s = dataclasses.replace(spread, vehicle=v)
            t0 = time.perf_counter()
            BatchSimulator(s).run()
            times[name].append(time.perf_counter() - t0)
    a, b = min(times['ideal']), min(times['multirotor'])
    runs = []
    for _ in range(repeats):
        with timed_own() as spent:
            t0 = time.perf_counter()
            BatchSimulator(dataclasses.replace(spread, vehicle=vehicle.MULTIROTOR)).run()
            whole = time.perf_counter() - t0
        runs.append((whole / (whole - sum(spent.values())), whole, dict(spent)))
    runs.sort(key=lambda run: run[0])
    ratios = [r for r, _, _ in runs]
    ratio, whole, spent = runs[len(runs) // 2]
    top = ', '.join(f'{k} {v:.3f}' for k, v in sorted(spent.items(), key=lambda kv: -kv[1])[:3])
    return (f'{maps} MAPs, {steps} steps: ideal {a:.2f} s, multirotor {b:.2f} s, ratio {b / a:.3f}; the vehicle\'s own '
            f'functions {sum(spent.values()):.3f} s of {whole:.2f} s, x {ratio:.3f} over the rest in the median of '
            f'{repeats} runs ({", ".join(f"{r:.3f}" for r in ratios)}; {top} s)')


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument('--seeds', type=int, default=5)
    ap.add_argument('--cost-only', action='store_true', help='only what the vehicle costs the simulator')
    ap.add_argument('--no-cost', action='store_true', help='leave out what the vehicle costs (it times runs)')
    args = ap.parse_args()
    if not args.cost_only:
        paper = load_scenario('paper')
        seeds = range(args.seeds)
        print("The paper's layout, Algorithm 2, 90 MAPs, 60 s, seeds 0-" f'{args.seeds - 1}:\n' + HEAD, flush=True)
        for label, v in (('ideal (the paper\'s)', vehicle.IDEAL), ('multirotor (shipped profile)', vehicle.MULTIROTOR)):
            print(table(label, [flown(dataclasses.replace(paper, seed=k, vehicle=v)) for k in seeds]), flush=True)
        print("\nThe radio of docs/links.md on the paper's layout, multirotor:\n" + HEAD, flush=True)
        for loss in (0.3, 0.5):
            radio = Links(delivery='alpha', z1=0.8, loss=loss, latency=2)
            rows = [flown(dataclasses.replace(paper, seed=k, vehicle=vehicle.MULTIROTOR, links=radio)) for k in seeds]
            print(table(f'alpha, z1 0.8, loss {loss:g}, latency 2', rows), flush=True)
    if args.no_cost:
        return 0
    print('\nWhat the vehicle costs the batch simulator (release square widened so every run is packable):', flush=True)
    for maps, steps in ((100, 600), (100, 200), (1000, 20)):  # the paper's 60 s; its first 20 s (release, transit)
        print(cost(maps, steps), flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
