"""What each rule of the demand allocation adds: every rule switched off alone, paired against all rules on.

Run: ./uav-flock exec python benchmarks/bench_ablation.py [--layouts 30] [--rules kept,swing,...]
     [--csv ablation.csv] [--every-kind]  (one row per run; the same command again runs only the rows
     missing from it; --every-kind: each rule off on all six kinds, the check before a rule is removed)
Layouts, kinds and draws are bench_motion's (layout n of `./uav-flock layouts --seed 0`, seed 0), plus
static12: the layout standing still, N = ceil(1.2 x LB), 60 s. Each rule is switched off on the kinds it
was made for and, when it acts on a still layout, static12 (KINDS_OF). Per rule and kind, paired by layout:
the share of time connected after convergence (0 for a run that never converges), R_c at the end, and the
runs that end covered and connected, with the change off - on and its bootstrap 95 % interval
(scipy.stats.bootstrap over the paired differences).
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import os
import numpy as np

import bench_motion
import resumable
from uav_agent.core import ablation
from uav_flock_tools.layouts import draw, policy_sets
from uav_flock_tools.study import cases
from world_sim.core import layouts
from world_sim.core.scenario import Scenario
from world_sim.shipped import load_scenario

KINDS_OF = {  # the kinds each rule was made for, then static12 where it acts on a still layout
    'carry': ('drift2', 'arrival'),
    'kept': ('drift2', 'arrival'), 'standing': ('drift2', 'crossing'),
    'swing': ('drift2',), 'tree': ('drift2', 'arrival'), 'chain': ('drift2',), 'passing': ('drift2', 'static12'),
    'straight': ('drift2',), 'vacate': ('wipeout', 'static12'), 'short': ('loss', 'static12'),
    'offset': ('drift2', 'static12'),
}
EVERY_KIND = ('drift2', 'crossing', 'arrival', 'loss', 'wipeout', 'static12')
FIELDS = ('connected', 'end_rc', 'ends_ok', 'converged')


def static12(lay: Scenario) -> Scenario:
    s = dataclasses.replace(lay, seed=0, survey='online', duration=60.0)
    return dataclasses.replace(s, maps=math.ceil(1.2 * layouts.floor(s).total))


def scenario_of(kind: str, n: int, lay: Scenario) -> tuple[Scenario, int]:
    """The run of a kind on layout n and the seed of its own draws, as bench_motion draws them."""
    if kind == 'static12':
        return static12(lay), n * 1000 + len(bench_motion.KINDS) + 7
    draw_seed = cases.draws(n, 0, kind)
    return cases.case(kind, lay, 0, np.random.default_rng(draw_seed)), draw_seed + cases.IN_FLIGHT


def run(job: tuple[str, str, int, Scenario, int]) -> dict[str, object]:
    rule, kind, n, s, draw_seed = job
    with ablation.switched_off([] if rule == 'none' else [rule]):
        r = bench_motion.run((kind, s, draw_seed))
    return {'rule': rule, 'kind': kind, 'layout': n, 'connected': r['connected'] or 0.0, 'end_rc': r['end_rc'],
            'ends_ok': r['ends_ok'], 'converged': r['converged']}


def table(rows: list[dict[str, str]], rules: list[str], kinds_of: dict[str, tuple[str, ...]]) -> str:
    by = {(r['rule'], r['kind'], int(r['layout'])): r for r in rows}
    out = ['| rule off | kind | runs | connected after convergence, all on | change off - on [95 % interval] | '
           'R_c at end, all on | change [95 %] | end covered and connected: on, off | verdict |',
           '|---|---|---|---|---|---|---|---|---|']
    for rule in rules:
        for kind in kinds_of[rule]:
            pairs = [(by[('none', kind, n)], by[(rule, kind, n)]) for (r, k, n) in by
                     if r == rule and k == kind and ('none', kind, n) in by]
            if not pairs:
                continue
            con = np.array([[float(a['connected']), float(b['connected'])] for a, b in pairs])
            rc = np.array([[float(a['end_rc']), float(b['end_rc'])] for a, b in pairs])
            ok = np.array([[float(a['ends_ok']), float(b['ends_ok'])] for a, b in pairs])
            dc, dr = con[:, 1] - con[:, 0], rc[:, 1] - rc[:, 0]
            (cl, ch), (rl, rh) = resumable.interval(dc), resumable.interval(dr)
            pays = ch < 0 or rh < 0  # switching it off costs, beyond the interval
            harms = cl > 0 or rl > 0
            same = not np.any(dc) and not np.any(dr)
            verdict = 'pays' if pays else 'costs' if harms else 'identical runs' if same else 'within noise'
            out.append(f'| {rule} | {kind} | {len(pairs)} | {100 * con[:, 0].mean():.1f} % | '
                       f'{100 * dc.mean():+.2f} [{100 * cl:+.2f}, {100 * ch:+.2f}] | {100 * rc[:, 0].mean():.1f} % | '
                       f'{100 * dr.mean():+.2f} [{100 * rl:+.2f}, {100 * rh:+.2f}] | '
                       f'{int(ok[:, 0].sum())}, {int(ok[:, 1].sum())} | {verdict} |')
    return '\n'.join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument('--layouts', type=int, default=30, help='random layouts (default: 30)')
    ap.add_argument('--rules', default=','.join(KINDS_OF), help='comma-separated (default: every rule)')
    ap.add_argument('--workers', type=int, default=os.cpu_count() or 1, help='processes (default: one a core)')
    ap.add_argument('--csv', default='ablation.csv', help='one row per run, kept across calls (default: ablation.csv)')
    ap.add_argument('--every-kind', action='store_true',
                    help='switch the rules off on all six kinds, not only those they were made for: the check '
                         'before a rule is removed')
    ap.add_argument('--table', action='store_true', help='only print the table of what --csv holds')
    args = ap.parse_args()
    rules = [r.strip() for r in args.rules.split(',') if r.strip()]
    if not rules or any(r not in KINDS_OF for r in rules):
        ap.error(f'--rules: choose from {", ".join(KINDS_OF)}')
    if args.layouts < 1 or args.workers < 1:
        ap.error('--layouts and --workers must be at least 1')
    kinds_of = {r: EVERY_KIND if args.every_kind else KINDS_OF[r] for r in rules}
    done = resumable.rows(args.csv)
    if not args.table:
        done = sweep(args, kinds_of, done)
    print(table(done, rules, kinds_of))
    return 0


def sweep(args: argparse.Namespace, kinds_of: dict[str, tuple[str, ...]],
          done: list[dict[str, str]]) -> list[dict[str, str]]:
    have = {(r['rule'], r['kind'], int(r['layout'])) for r in done}
    kinds = sorted({k for ks in kinds_of.values() for k in ks})
    flock = policy_sets(load_scenario('paper'))['default']
    jobs = []
    for n, lay in enumerate(draw('paper', args.layouts, (3, 6), 0, 'ideal')):
        lay = dataclasses.replace(lay, flock=flock)
        for kind in kinds:
            s, draw_seed = scenario_of(kind, n, lay)
            jobs += [(rule, kind, n, s, draw_seed) for rule in ('none', *kinds_of)
                     if (rule == 'none' or kind in kinds_of[rule]) and (rule, kind, n) not in have]
    return resumable.sweep(args.csv, ['rule', 'kind', 'layout', *FIELDS], jobs, run, args.workers, done)


if __name__ == '__main__':
    raise SystemExit(main())
