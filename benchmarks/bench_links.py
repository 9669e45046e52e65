"""An imperfect radio between MAPs: how often the formation stays connected when neighbour states are lost,
lost in bursts, or late, on random layouts, still and drifting.

Run: ./uav-flock exec python benchmarks/bench_links.py [--layouts 30 --seeds 1 --kinds static,drift2]
     [--channels perfect,alpha.3L2,loss.5,loss.3B20] [--csv links.csv]  (one row per run, kept across calls:
     the same command again runs only the rows missing from it; --table prints what the CSV holds)
Layout n is layout n of `./uav-flock layouts --seed 0`, with the default policies and the online survey.
  static   the layout standing still, N = ceil(1.5 x LB), 60 s
  drift2   bench_motion's: a cluster picked at random drifts at 2 m/s, N = ceil(1.5 x the largest LB), 90 s
Channels (the scenario's links:, docs/scenarios.md): `perfect` (none), or a name of the form
[alpha][loss]<p>[B<burst>][L<latency>], e.g. alpha.3L2 = {delivery: alpha, z1: 0.8, loss: 0.3, latency: 2}.
The usable graph links two MAPs whose delivery probability is at least 0.5 (links.USABLE; under disc, the
disc graph). Per run: the first step covered (R_c >= 95 %) with the usable graph connected ("convergence");
after it, the share of time the usable graph and the disc graph are connected and the longest outage of
the usable graph; success: covered and the usable graph connected over the last 10 s.
"""
from __future__ import annotations

import argparse
import csv
import dataclasses
import math
import os
import re
import time
from concurrent.futures import ProcessPoolExecutor, as_completed

import numpy as np
from scipy.stats import bootstrap

import bench_motion
from uav_agent.core import links
from uav_flock_tools.batch import BatchSimulator
from uav_flock_tools.layouts import draw, policy_sets
from world_sim.core import layouts, physics
from world_sim.core.scenario import Scenario
from world_sim.shipped import load_scenario

KINDS = ('static', 'drift2')
CHANNELS = ('perfect', 'alpha.3L2', 'loss.5', 'loss.3B20')
FIELDS = ('converged', 'usable', 'disc', 'outage', 'success', 'end_rc')
HELD_S = 10.0


def channel(name: str) -> links.Links:
    """A channel by its name (module docstring); ValueError for a name of no channel."""
    if name == 'perfect':
        return links.Links()
    m = re.fullmatch(r'(alpha)?(?:loss)?(\d*\.?\d+)(?:B(\d*\.?\d+))?(?:L(\d+))?', name)
    if not m:
        raise ValueError(f'{name!r}: expected perfect or [alpha][loss]<p>[B<burst>][L<latency>]')
    alpha, loss, burst, latency = m.groups()
    return links.check(links.Links('alpha' if alpha else 'disc', 0.8, float(loss), float(burst or 1.0),
                                   int(latency or 0), max(10, int(latency or 0))))


def scenario_of(kind: str, n: int, lay: Scenario, seed: int, name: str) -> tuple[Scenario, int]:
    if kind == 'static':
        s = dataclasses.replace(lay, seed=seed, survey='online', duration=60.0)
        s, draw_seed = dataclasses.replace(s, maps=math.ceil(1.5 * layouts.floor(s).total)), n * 1000 + seed * 10 + 9
    else:
        draw_seed = n * 1000 + seed * 10 + bench_motion.KINDS.index(kind)
        s = bench_motion.case(kind, lay, seed, np.random.default_rng(draw_seed))
    return dataclasses.replace(s, links=channel(name)), draw_seed


def usable_connected(sim: BatchSimulator) -> bool:
    """Whether the live MAPs' usable graph is connected now."""
    s = sim.scenario
    rows = np.flatnonzero(sim.alive)
    q = sim.q[rows]
    pairs = physics.neighbour_pairs(q, s.flock.r)
    keep = links.delivery(s.links, np.linalg.norm(q[pairs[:, 0]] - q[pairs[:, 1]], axis=1), s.flock.r) >= links.USABLE
    return physics.components(pairs[keep], len(rows)) == 1


def run(job: tuple[str, str, int, int, Scenario]) -> dict[str, object]:
    kind, name, n, seed, s = job
    sim = BatchSimulator(s)
    up = []
    for _ in range(s.steps):
        up.append(usable_connected(sim))
        sim.step()
    up.append(usable_connected(sim))
    sim.step(integrate=False)
    m = sim.result().metrics
    ok_usable, covered = np.array(up), m[:, 2] >= 0.95
    held = int(round(HELD_S / s.dt))
    out: dict[str, object] = {'kind': kind, 'channel': name, 'layout': n, 'seed': seed, 'converged': '', 'usable': 0.0,
                              'disc': 0.0, 'outage': '', 'end_rc': float(m[-1, 2]),
                              'success': float((covered & ok_usable)[-held:].all())}
    both = covered & ok_usable
    if both.any():
        first = int(np.argmax(both))
        out.update(converged=float(m[first, 1]), usable=float(ok_usable[first:].mean()),
                   disc=float((m[first:, 3] > 0).mean()), outage=bench_motion.outage_s(~ok_usable[first:], s.dt))
    return out


def interval(v: np.ndarray) -> str:
    if len(v) < 2 or np.all(v == v[0]):
        return f'{100 * v.mean():.1f}'
    ci = bootstrap((v,), np.mean, n_resamples=2000, random_state=0).confidence_interval
    return f'{100 * v.mean():.1f} [{100 * ci.low:.1f}, {100 * ci.high:.1f}]'


def table(rows: list[dict[str, str]]) -> str:
    out = ['| kind | channel | runs | success | usable graph connected after convergence: mean [95 %] | worst run | '
           'disc graph connected: mean | longest usable outage: median, worst | never converged |',
           '|---|---|---|---|---|---|---|---|---|']
    for kind in KINDS:
        for name in sorted({r['channel'] for r in rows}, key=lambda c: (c != 'perfect', c)):
            cell = [r for r in rows if r['kind'] == kind and r['channel'] == name]
            if not cell:
                continue
            conv = [r for r in cell if r['converged'] != '']
            usable = np.array([float(r['usable']) for r in cell])
            disc = np.array([float(r['disc']) for r in conv]) if conv else np.zeros(1)
            outage = np.array([float(r['outage']) for r in conv]) if conv else np.zeros(1)
            out.append(f'| {kind} | {name} | {len(cell)} | {sum(float(r["success"]) for r in cell):.0f}/{len(cell)} | '
                       f'{interval(usable)} | {100 * usable.min():.1f} | {100 * disc.mean():.1f} | '
                       f'{np.median(outage):.1f} s, {outage.max():.1f} s | {len(cell) - len(conv)} |')
    return '\n'.join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument('--layouts', type=int, default=30, help='random layouts (default: 30)')
    ap.add_argument('--seeds', type=int, default=1, help='seeds per layout (default: 1)')
    ap.add_argument('--kinds', default=','.join(KINDS), help=f'comma-separated, of: {", ".join(KINDS)}')
    ap.add_argument('--channels', default=','.join(CHANNELS), help=f'comma-separated (default: {",".join(CHANNELS)})')
    ap.add_argument('--workers', type=int, default=os.cpu_count() or 1, help='processes (default: one a core)')
    ap.add_argument('--csv', default='links.csv', help='one row per run, kept across calls (default: links.csv)')
    ap.add_argument('--table', action='store_true', help='only print the table of what --csv holds')
    args = ap.parse_args()
    kinds = [k for k in args.kinds.split(',') if k]
    names = [c for c in args.channels.split(',') if c]
    if not kinds or any(k not in KINDS for k in kinds):
        ap.error(f'--kinds: choose from {", ".join(KINDS)}')
    try:
        [channel(c) for c in names]
    except ValueError as exc:
        ap.error(f'--channels: {exc}')
    done: list[dict[str, str]] = []
    if os.path.exists(args.csv):
        with open(args.csv, newline='') as f:
            done = list(csv.DictReader(f))
    if not args.table:
        done = sweep(args, kinds, names, done)
    print(table(done))
    return 0


def sweep(args: argparse.Namespace, kinds: list[str], names: list[str], done: list[dict[str, str]]) -> list[dict[str, str]]:
    have = {(r['kind'], r['channel'], int(r['layout']), int(r['seed'])) for r in done}
    flock = policy_sets(load_scenario('paper'))['default']
    jobs = []
    for n, lay in enumerate(draw('paper', args.layouts, (3, 6), 0)):
        lay = dataclasses.replace(lay, flock=flock)
        for seed in range(args.seeds):
            for kind in kinds:
                jobs += [(kind, c, n, seed, scenario_of(kind, n, lay, seed, c)[0]) for c in names
                         if (kind, c, n, seed) not in have]
    print(f'{len(jobs)} runs to go ({len(have)} in {args.csv}), {args.workers} processes', flush=True)
    t0 = time.perf_counter()
    new = not done
    with open(args.csv, 'a', newline='') as f, ProcessPoolExecutor(max_workers=args.workers) as pool:
        out = csv.DictWriter(f, fieldnames=['kind', 'channel', 'layout', 'seed', *FIELDS])
        if new:
            out.writeheader()
        futures = [pool.submit(run, job) for job in jobs]
        try:
            for i, fut in enumerate(as_completed(futures), 1):
                row = fut.result()
                out.writerow(row)
                f.flush()
                done.append({k: str(v) for k, v in row.items()})
                if i % 10 == 0 or i == len(jobs):
                    left = (time.perf_counter() - t0) / i * (len(jobs) - i)
                    print(f'  {i}/{len(jobs)} runs, {time.perf_counter() - t0:.0f} s, about {left / 60:.0f} min left',
                          flush=True)
        except KeyboardInterrupt:
            for fut in futures:
                fut.cancel()
            print(f'interrupted: {len(done)} rows kept in {args.csv}; the same command goes on from there')
            raise SystemExit(130)
    return done


if __name__ == '__main__':
    raise SystemExit(main())
