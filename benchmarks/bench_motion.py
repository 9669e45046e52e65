"""Moving users and lost MAPs on random layouts, with the case drawn at random too: how long the network holds.

Run: ./uav-flock exec python benchmarks/bench_motion.py [--layouts 30 --seeds 2 --kinds drift2,loss,...]
     [--per-run runs.csv]  (one row per run: which layout, seed and case failed, to look into)
Layout n is layout n of `./uav-flock layouts --seed 0` (3 to 6 clusters); default policies, online survey,
batch runs. Per layout and seed, one case of each kind, drawn with the job's own generator:
  drift1/2/3  a cluster picked at random drifts in a random direction at 1, 2 or 3 m/s for the whole 90 s;
              N = ceil(1.5 x the largest LB the layout reaches along the drift, sampled every 5 s)
  crossing    two neighbouring clusters drift through each other's place (each is at the other's at 45 s
              and as far beyond it by 90 s); N as for a drift
  loss        a static layout, N = ceil(1.8 x LB), 30 % of the MAPs fail at 45 s (the scenario's random
              failure), 120 s
  wipeout     the same, but the MAPs that fail at 45 s are all the MAPs of one role then (a cluster's
              servers or an edge's relays, the role picked at random among those with MAPs)
  arrival     a static layout plus a cluster of 300 users appearing at 40 s, 100 to 150 m beyond the
              layout's farthest cluster in a random direction; N = ceil(1.5 x LB with it), 100 s
Per kind: after the first step with R_c >= 95 % and lambda2 > 0 ("convergence"), the fraction of time
connected (mean, 10th percentile, worst run), the longest outage (median and worst run), the mean R_c;
for the kinds with an event (loss, wipeout, arrival) the time from the event to the first step covered
and connected again, and how many runs end covered and connected over their last 10 s. Then where the
split time after convergence goes, by what the split cuts off from the largest component: at most three
MAPs (each counted as on its way to a new role, a relay or a server) or a larger piece (a cluster's servers,
part of a chain); and the larger pieces by what changed last within 20 s before: the spanning tree swapped
an edge for one that shares a cluster with it (its relays swing) or for one that shares none (the old chain
stands), a surveyed cluster ended (merged into another, or left) or began (parted from another, or arrived).
"""
from __future__ import annotations

import argparse
import csv
import dataclasses
import math
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Optional

import numpy as np

from uav_agent.core.state import M1, Told
from uav_flock_tools.layouts import draw, policy_sets
from uav_flock_tools.batch import BatchSimulator
from uav_flock_tools.study.cases import EVENT_S, HELD_S, IN_FLIGHT, case, draws, figures, outage_s, wipe_at  # noqa: F401 (case, outage_s: bench_links)
from world_sim.core import physics
from world_sim.core.scenario import Scenario
from world_sim.shipped import load_scenario

KINDS = ('drift1', 'drift2', 'drift3', 'crossing', 'loss', 'wipeout', 'arrival')
FEW = 3        # up to this many MAPs cut off are told apart by what each was doing; more are a piece
CUT = ('transit', 'relay', 'server', 'piece')
AFTER = ('swing', 'standing', 'ended', 'began', 'none')  # what changed last before a larger piece split off
RECENT_S = 20.0  # a change longer ago than this is 'none'


def cut_off(sim: BatchSimulator) -> np.ndarray:
    """What a split cuts off from the largest component now, as shares of CUT (all zero when connected)."""
    share = np.zeros(len(CUT))
    rows = np.flatnonzero(sim.alive)
    labels = physics.component_labels(physics.neighbour_pairs(sim.q[rows], sim.scenario.flock.r), len(rows))
    sizes = np.bincount(labels)
    if len(sizes) < 2:
        return share
    cut = rows[labels != sizes.argmax()]
    if len(cut) > FEW:
        share[CUT.index('piece')] = 1.0
        return share
    for i in cut:
        m = sim.memory[i]
        share[CUT.index('transit' if Told.of(m).block.transit else 'relay' if m.mode == M1 else 'server')] += 1.0 / len(cut)
    return share


def change(was: tuple[int, tuple], now: tuple[int, tuple]) -> Optional[str]:
    """What changed between two (live clusters, spanning tree) pairs, as an AFTER name; None if nothing."""
    (live0, tree0), (live1, tree1) = was, now
    if live1 != live0:
        return 'ended' if live0 & ~live1 else 'began'
    if tree1 == tree0:
        return None
    ends = {k for e in tree1 if e not in tree0 for k in e}
    return 'swing' if any(ends & set(e) for e in tree0 if e not in tree1) else 'standing'


def run(job: tuple[str, Scenario, int]) -> dict[str, Optional[float]]:
    kind, s, draw_seed = job
    rng = np.random.default_rng(draw_seed)
    sim = BatchSimulator(s)
    event = EVENT_S.get(kind)
    cut = [cut_off(sim)]  # row k: the state metrics row k records
    follows = [AFTER.index('none')]  # row k: what changed last before step k, for a larger piece then
    known = sim.clusters
    tree = (known.live, known.mst(known.live))
    last, since = 'none', -math.inf
    for _ in range(s.steps):
        wipe_at(kind, sim, rng)
        sim.step()
        cut.append(cut_off(sim))
        if sim.clusters is not known:  # the tree changes only with the clusters the MAPs are told of
            known = sim.clusters
            now = (known.live, known.mst(known.live))
            what = change(tree, now)
            if what is not None:
                last, since = what, sim.world.k * s.dt
            tree = now
        follows.append(AFTER.index(last if sim.world.k * s.dt - since < RECENT_S else 'none'))
    sim.step(integrate=False)
    m = sim.result().metrics
    out: dict[str, Optional[float]] = {**figures(m, s.dt, event), **{f'split_{c}': None for c in CUT},
                                       **{f'piece_after_{a}': None for a in AFTER}}
    ok = (m[:, 2] >= 0.95) & (m[:, 3] > 0)
    if ok.any():
        first = int(np.argmax(ok))
        out.update({f'split_{c}': float(x) for c, x in zip(CUT, np.sum(cut[first:], axis=0) * s.dt)})
        piece = np.array(cut)[first:, CUT.index('piece')] > 0
        out.update({f'piece_after_{a}': float(np.sum(piece & (np.array(follows[first:]) == i)) * s.dt)
                    for i, a in enumerate(AFTER)})
    return out


def pct(v: float) -> str:
    return f'{100 * v:.1f} %'


def report(kind: str, results: list[dict[str, Optional[float]]]) -> str:
    conv = [r for r in results if r['connected'] is not None]
    if not conv:
        return f'| {kind} | 0/{len(results)} | — | — | — | — | — | — | {int(sum(r["ends_ok"] for r in results))}/{len(results)} |'
    con = np.array([r['connected'] for r in conv])
    out = np.array([r['outage'] for r in conv])
    rec = [r['recovery'] for r in results if r['recovery'] is not None]
    recovery = '—' if kind not in EVENT_S else (
        f'{np.median(rec):.1f} s ({len(rec)}/{len(results)})' if rec else f'never (0/{len(results)})')
    return (f'| {kind} | {len(conv)}/{len(results)} | {pct(con.mean())} | {pct(np.percentile(con, 10))} | '
            f'{pct(con.min())} | {np.median(out):.1f} s, {out.max():.1f} s | '
            f'{pct(np.mean([r["rc"] for r in conv]))} | {recovery} | {int(sum(r["ends_ok"] for r in results))}/{len(results)} |')


def where_split(kind: str, results: list[dict[str, Optional[float]]]) -> str:
    """Seconds split after convergence per run (mean), by what the split cut off."""
    conv = [r for r in results if r['connected'] is not None]
    if not conv:
        return f'| {kind} | — |' + ' — |' * len(CUT)
    by = np.array([[r[f'split_{c}'] for c in CUT] for r in conv])
    total = by.sum(axis=1).mean()
    shares = ' | '.join(f'{x:.2f} s ({100 * x / total:.0f} %)' if total > 0 else f'{x:.2f} s' for x in by.mean(axis=0))
    return f'| {kind} | {total:.2f} s | {shares} |'


def where_pieces(kind: str, results: list[dict[str, Optional[float]]]) -> str:
    """Seconds per run (mean) with a larger piece cut off after convergence, by what changed last before."""
    conv = [r for r in results if r['connected'] is not None]
    if not conv:
        return f'| {kind} | — |' + ' — |' * len(AFTER)
    by = np.array([[r[f'piece_after_{a}'] for a in AFTER] for r in conv]).mean(axis=0)
    return f'| {kind} | {by.sum():.2f} s | ' + ' | '.join(f'{x:.2f} s' for x in by) + ' |'


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument('--layouts', type=int, default=30, help='random layouts (default: 30)')
    ap.add_argument('--seeds', type=int, default=2, help='seeds per layout (default: 2)')
    ap.add_argument('--kinds', default=','.join(KINDS), help=f'comma-separated, of: {", ".join(KINDS)} (default: all)')
    ap.add_argument('--workers', type=int, default=2, help='processes (default: 2)')
    ap.add_argument('--per-run', metavar='CSV', help='also write one row per run (kind, layout, seed, figures)')
    args = ap.parse_args()
    kinds = [k.strip() for k in args.kinds.split(',') if k.strip()]
    if not kinds or any(k not in KINDS for k in kinds):
        ap.error(f'--kinds: choose from {", ".join(KINDS)}')
    if args.layouts < 1 or args.seeds < 1 or args.workers < 1:
        ap.error('--layouts, --seeds and --workers must be at least 1')
    flock = policy_sets(load_scenario('paper'))['default']
    jobs, where = [], []
    for n, lay in enumerate(draw('paper', args.layouts, (3, 6), 0, 'ideal')):
        lay = dataclasses.replace(lay, flock=flock)
        for seed in range(args.seeds):
            for kind in kinds:
                draw_seed = draws(n, seed, kind)  # the case's own draws, reproducible
                rng = np.random.default_rng(draw_seed)
                jobs.append((kind, case(kind, lay, seed, rng), draw_seed + IN_FLIGHT))
                where.append((kind, n, seed))
    print(f'{len(jobs)} runs: {args.layouts} layouts x {args.seeds} seeds x {len(kinds)} kinds, '
          f'{args.workers} processes', flush=True)
    t0 = time.perf_counter()
    results = []
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        for i, r in enumerate(pool.map(run, jobs), 1):
            results.append(r)
            if i % 10 == 0 or i == len(jobs):
                print(f'  {i}/{len(jobs)} runs, {time.perf_counter() - t0:.0f} s', flush=True)
    print('\n| kind | runs converged | time connected after convergence: mean | 10th percentile | worst run | '
          'longest outage: median, worst | mean R_c | recovery after the event: median (runs) | '
          f'runs ending covered and connected ({HELD_S:g} s) |')
    print('|---|---|---|---|---|---|---|---|---|')
    for kind in kinds:
        print(report(kind, [r for (k, _, _), r in zip(jobs, results) if k == kind]))
    print(f'\n| kind | split after convergence, per run | cut off: up to {FEW} MAPs on their way to a new role | '
          f'up to {FEW} relays | up to {FEW} servers | a larger piece |')
    print('|---|---|---|---|---|---|')
    for kind in kinds:
        print(where_split(kind, [r for (k, _, _), r in zip(jobs, results) if k == kind]))
    print(f'\n| kind | a larger piece cut off, per run | within {RECENT_S:g} s of: an edge swapped for one sharing a '
          'cluster (swing) | for one sharing none (standing) | a cluster ended (merged, left) | a cluster began '
          '(parted, arrived) | none of these |')
    print('|---|---|---|---|---|---|---|')
    for kind in kinds:
        print(where_pieces(kind, [r for (k, _, _), r in zip(jobs, results) if k == kind]))
    if args.per_run:
        fields = list(results[0])
        with open(args.per_run, 'w', newline='') as f:
            out = csv.writer(f)
            out.writerow(['kind', 'layout', 'seed', *fields])
            out.writerows([*w, *('' if r[k] is None else f'{r[k]:.4g}' for k in fields)] for w, r in zip(where, results))
        print(f'one row per run in {args.per_run}')
    print(f'\n{time.perf_counter() - t0:.0f} s in all')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
