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

from uav_agent.core.clusters import mst_edges
from uav_agent.core.state import M1, Told
from uav_flock_tools.layouts import draw, policy_sets
from uav_flock_tools.batch import BatchSimulator
from world_sim.core import layouts, physics
from world_sim.core.scenario import Cluster, Scenario
from world_sim.shipped import load_scenario

KINDS = ('drift1', 'drift2', 'drift3', 'crossing', 'loss', 'wipeout', 'arrival')
EVENT_S = {'loss': 45.0, 'wipeout': 45.0, 'arrival': 40.0}
HELD_S = 10.0  # a run "ends covered and connected" when it is so over its last HELD_S
FEW = 3        # up to this many MAPs cut off are told apart by what each was doing; more are a piece
CUT = ('transit', 'relay', 'server', 'piece')
AFTER = ('swing', 'standing', 'ended', 'began', 'none')  # what changed last before a larger piece split off
RECENT_S = 20.0  # a change longer ago than this is 'none'


def lb_along(s: Scenario, until: float) -> int:
    """The largest floor LB of the layout as its drifting clusters move, sampled every 5 s."""
    most = 0
    for t in np.arange(0.0, until + 1e-9, 5.0):
        moved = tuple(dataclasses.replace(c, center=(c.center[0] + c.velocity[0] * t, c.center[1] + c.velocity[1] * t))
                      for c in s.clusters)
        most = max(most, layouts.floor(dataclasses.replace(s, clusters=moved)).total)
    return most


def case(kind: str, lay: Scenario, seed: int, rng: np.random.Generator) -> Scenario:
    """The scenario of one run of a kind on a layout, its random choices drawn from rng."""
    s = dataclasses.replace(lay, seed=seed, survey='online')
    clusters = list(s.clusters)
    if kind.startswith('drift'):
        heading = rng.uniform(0, 2 * math.pi)
        speed = float(kind[len('drift'):])
        c = int(rng.integers(len(clusters)))
        clusters[c] = dataclasses.replace(clusters[c], velocity=(round(speed * math.cos(heading), 3),
                                                                 round(speed * math.sin(heading), 3)))
    elif kind == 'crossing':
        a, b = mst_edges(np.array([c.center for c in clusters]))[int(rng.integers(len(clusters) - 1))]
        ca, cb = np.array(clusters[a].center), np.array(clusters[b].center)
        v = (cb - ca) * 2.0 / 90.0  # each is at the other's place at 45 s and as far beyond by 90 s
        clusters[a] = dataclasses.replace(clusters[a], velocity=(round(v[0], 3), round(v[1], 3)))
        clusters[b] = dataclasses.replace(clusters[b], velocity=(round(-v[0], 3), round(-v[1], 3)))
    elif kind == 'arrival':
        xy = np.array([c.center for c in clusters])
        mid = xy.mean(axis=0)
        heading = rng.uniform(0, 2 * math.pi)
        u = np.array([math.cos(heading), math.sin(heading)])
        far = float(np.max(xy @ u - mid @ u))
        at = mid + u * (far + rng.uniform(100.0, 150.0))
        clusters.append(Cluster(center=(round(at[0], 1), round(at[1], 1)), spread=14.0, size=300,
                                start=EVENT_S['arrival']))
    s = dataclasses.replace(s, clusters=tuple(clusters))
    if kind in ('loss', 'wipeout'):
        s = dataclasses.replace(s, duration=120.0, maps=math.ceil(1.8 * layouts.floor(s).total))
        if kind == 'loss':
            s = dataclasses.replace(s, fail_at=EVENT_S['loss'], fail_fraction=0.3)
        return s
    if kind == 'arrival':
        return dataclasses.replace(s, duration=100.0, maps=math.ceil(1.5 * layouts.floor(s).total))
    return dataclasses.replace(s, duration=90.0, maps=math.ceil(1.5 * lb_along(s, 90.0)))


def wipe_out(sim: BatchSimulator, rng: np.random.Generator) -> int:
    """Drop every live MAP of one role picked at random: a cluster's servers or an edge's relays."""
    roles: dict[tuple, list[int]] = {}
    for i in np.flatnonzero(sim.alive).tolist():
        m = sim.memory[i]
        roles.setdefault(('edge', m.bridge) if m.mode == M1 and m.bridge else ('cluster', m.goal), []).append(i)
    keys = sorted(roles, key=str)
    ids = roles[keys[int(rng.integers(len(keys)))]]
    sim.world.drop(np.array(ids))
    return len(ids)


def outage_s(down: np.ndarray, dt: float) -> float:
    """The longest run of True in down, in seconds."""
    longest = run = 0
    for d in down.tolist():
        run = run + 1 if d else 0
        longest = max(longest, run)
    return longest * dt


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
        if kind == 'wipeout' and abs(sim.world.k * s.dt - event) < s.dt / 2:
            wipe_out(sim, rng)
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
    t, rc, connected = m[:, 1], m[:, 2], m[:, 3] > 0
    ok = (rc >= 0.95) & connected
    out: dict[str, Optional[float]] = {'converged': None, 'connected': None, 'outage': None, 'rc': None,
                                       'recovery': None, 'ends_ok': None, **{f'split_{c}': None for c in CUT},
                                       **{f'piece_after_{a}': None for a in AFTER}}
    held = int(round(HELD_S / s.dt))
    out['ends_ok'] = float(ok[-held:].all())
    out['end_rc'], out['end_components'] = float(rc[-1]), float(m[-1, 5])
    if event is not None:
        after = np.flatnonzero(ok & (t >= event + s.dt / 2))
        out['recovery'] = float(t[after[0]] - event) if len(after) else None
    if ok.any():
        first = int(np.argmax(ok))
        out.update(converged=float(t[first]), connected=float(connected[first:].mean()),
                   outage=outage_s(~connected[first:], s.dt), rc=float(rc[first:].mean()))
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
    for n, lay in enumerate(draw('paper', args.layouts, (3, 6), 0)):
        lay = dataclasses.replace(lay, flock=flock)
        for seed in range(args.seeds):
            for kind in kinds:
                draw_seed = n * 1000 + seed * 10 + KINDS.index(kind)  # the case's own draws, reproducible
                rng = np.random.default_rng(draw_seed)
                jobs.append((kind, case(kind, lay, seed, rng), draw_seed + 7))
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
