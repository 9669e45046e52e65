"""An imperfect radio between MAPs: how often the formation stays connected when neighbour states are lost,
lost in bursts, or late, on random layouts, still and drifting.

Run: ./uav-flock exec python benchmarks/bench_links.py [--layouts 30 --seeds 1 --kinds static,drift2]
     [--channels perfect,alpha.3L2,loss.5,loss.3B20 | grid] [--variants all,predict+gone] [--csv links.csv]
     (one row per run, kept across calls: the same command again runs only the rows missing from it; --table
     prints what the CSV holds)
Layout n is layout n of `./uav-flock layouts --seed 0`, with the default policies and the online survey.
  static   the layout standing still, N = ceil(1.5 x LB), 60 s
  drift2   bench_motion's: a cluster picked at random drifts at 2 m/s, N = ceil(1.5 x the largest LB), 90 s
  paper    the paper's layout, 90 MAPs, with its own policies (Algorithm 2), seed n for layout n, 60 s
  paper_demand  the same with the default policies (the demand allocation)
Channels (the scenario's links:, docs/scenarios.md): `perfect` (none), or a name of the form
[alpha][loss]<p>[B<burst>][L<latency>][T<ttl>], e.g. alpha.3L2 = {delivery: alpha, z1: 0.8, loss: 0.3, latency: 2}
(ttl 10 unless T says otherwise).
A variant names the rules switched off (core/ablation.py; `all`: none off), e.g. predict+gone: stale neighbour
states used as they came, before the MAP predicted them and dropped the ones gone. Variants are paired by run.
The usable graph links two MAPs whose delivery probability is at least 0.5 (links.USABLE; under disc, the
disc graph). Per run: the first step covered (R_c >= 95 %) with the usable graph connected ("convergence");
after it, the share of time the usable graph and the disc graph are connected and the longest outage of
the usable graph; success: covered and the usable graph connected over the last 10 s (study.cases.figures).
studies/links.yaml and studies/links-grid.yaml fly the same runs as a study, on Dask (docs/studies.md): rows
equal to these (connected = usable, ends_ok = success), on one machine or a cluster.
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import re
from pathlib import Path

import numpy as np

import resumable
from uav_agent.core import ablation, links
from uav_flock_tools.batch import BatchSimulator
from uav_flock_tools.layouts import draw, policy_sets
from uav_flock_tools.study import cases
from world_sim.core.scenario import Scenario
from world_sim.shipped import load_scenario

KINDS = ('static', 'drift2', 'paper', 'paper_demand')
CHANNELS = ('perfect', 'alpha.3L2', 'loss.5', 'loss.3B20')
# `--channels grid`: loss 0 / 0.2 / 0.4 / 0.6, disc and alpha (z1 = 0.8 r), latency 0 and 3 steps.
GRID = tuple(f'{"alpha" if alpha else "loss"}{loss}{"L3" if late else ""}'
             for alpha in (False, True) for late in (False, True) for loss in ('0', '.2', '.4', '.6'))
FIELDS = ('converged', 'usable', 'disc', 'outage', 'success', 'end_rc')


def channel(name: str) -> links.Links:
    """A channel by its name (module docstring); ValueError for a name of no channel."""
    if name == 'perfect':
        return links.Links()
    m = re.fullmatch(r'(alpha)?(?:loss)?(\d*\.?\d+)(?:B(\d*\.?\d+))?(?:L(\d+))?(?:T(\d+))?', name)
    if not m:
        raise ValueError(f'{name!r}: expected perfect or [alpha][loss]<p>[B<burst>][L<latency>][T<ttl>]')
    alpha, loss, burst, latency, ttl = m.groups()
    return links.check(links.Links('alpha' if alpha else 'disc', 0.8, float(loss), float(burst or 1.0),
                                   int(latency or 0), int(ttl) if ttl else max(10, int(latency or 0))))


def scenario_of(kind: str, n: int, lay: Scenario, seed: int, name: str) -> tuple[Scenario, int]:
    if kind.startswith('paper'):
        s = load_scenario('paper').with_overrides(maps=90, seed=n * 100 + seed, duration=60.0)
        if kind == 'paper_demand':
            s = dataclasses.replace(s, flock=lay.flock)
        return dataclasses.replace(s, links=channel(name)), n
    draw_seed = cases.draws(n, seed, kind)
    s = cases.case(kind, lay, seed, np.random.default_rng(draw_seed))
    return dataclasses.replace(s, links=channel(name)), draw_seed


def run(job: tuple[str, str, str, int, int, Scenario]) -> dict[str, object]:
    variant, kind, name, n, seed, s = job
    with ablation.switched_off(off(variant)):
        f = cases.figures(BatchSimulator(s).run().metrics, s.dt, None)  # connected: the usable graph's lambda2
    blank = {'converged': '', 'outage': ''}
    return {'variant': variant, 'kind': kind, 'channel': name, 'layout': n, 'seed': seed,
            **{k: blank[k] if f[k] is None else f[k] for k in blank}, 'usable': f['connected'] or 0.0,
            'disc': f['disc'] or 0.0, 'success': f['ends_ok'], 'end_rc': f['end_rc']}


def off(variant: str) -> set[str]:
    """The rules a variant switches off."""
    return set() if variant == 'all' else set(variant.split('+'))


def acts(variant: str, name: str) -> bool:
    """Whether a variant can differ from `all` over channel `name`: the channel's rules do nothing under the
    paper's channel, so those runs would only repeat `all`."""
    return variant == 'all' or not (channel(name).perfect and off(variant) <= set(ablation.CHANNEL_RULES))


def interval(v: np.ndarray) -> str:
    low, high = resumable.interval(v)
    return f'{100 * v.mean():.1f}' if low == high else f'{100 * v.mean():.1f} [{100 * low:.1f}, {100 * high:.1f}]'


def paired(cell: list[dict[str, str]], rows: list[dict[str, str]]) -> str:
    """The change in usable-connected share against the same runs with all rules on."""
    base = {(r['kind'], r['channel'], r['layout'], r['seed']): float(r['usable']) for r in rows if r['variant'] == 'all'}
    d = np.array([float(r['usable']) - base[key] for r in cell
                  if (key := (r['kind'], r['channel'], r['layout'], r['seed'])) in base])
    return f'{100 * d.mean():+.1f} [{interval(d).split("[")[-1]}' if len(d) > 1 and np.any(d) else f'{100 * d.mean():+.1f}' if len(d) else ''


def table(rows: list[dict[str, str]]) -> str:
    out = ['| kind | channel | variant | runs | success | usable graph connected after convergence: mean [95 %] | worst run | '
           'disc graph connected: mean | longest usable outage: median, worst | never converged | '
           'usable connected, paired change against all rules on [95 %] |',
           '|---|---|---|---|---|---|---|---|---|---|---|']
    for kind in KINDS:
        for name, variant in sorted({(r['channel'], r['variant']) for r in rows},
                                    key=lambda c: (c[0] != 'perfect', c[0], c[1] != 'all', c[1])):
            cell = [r for r in rows if r['kind'] == kind and r['channel'] == name and r['variant'] == variant]
            if not cell:
                continue
            conv = [r for r in cell if r['converged'] != '']
            usable = np.array([float(r['usable']) for r in cell])
            disc = np.array([float(r['disc']) for r in conv]) if conv else np.zeros(1)
            outage = np.array([float(r['outage']) for r in conv]) if conv else np.zeros(1)
            out.append(f'| {kind} | {name} | {variant} | {len(cell)} | {sum(float(r["success"]) for r in cell):.0f}/{len(cell)} | '
                       f'{interval(usable)} | {100 * usable.min():.1f} | {100 * disc.mean():.1f} | '
                       f'{np.median(outage):.1f} s, {outage.max():.1f} s | {len(cell) - len(conv)} | '
                       f'{paired(cell, rows) if variant != "all" else ""} |')
    return '\n'.join(out)


def against_loss(rows: list[dict[str, str]], path: Path) -> Path:
    """The share of time the usable graph is connected after convergence against the channel's loss, a panel
    per kind, a line per delivery, burst, latency and variant (mean over runs, with its 95 % interval)."""
    import matplotlib.pyplot as plt
    from uav_flock_tools import plots
    kinds = [k for k in KINDS if any(r['kind'] == k for r in rows)]
    fig, axes = plt.subplots(1, len(kinds), figsize=(5.2 * len(kinds), 4.0), squeeze=False)
    for ax, kind in zip(axes[0], kinds):
        lines: dict[str, list[tuple[float, float, float, float]]] = {}
        for name, variant in sorted({(r['channel'], r['variant']) for r in rows if r['kind'] == kind}):
            c = channel(name)
            v = np.array([float(r['usable']) for r in rows if (r['kind'], r['channel'], r['variant']) == (kind, name, variant)])
            low, high = resumable.interval(v)
            label = (f'{c.delivery}, burst {c.burst:g}, latency {c.latency}' + ('' if variant == 'all' else f', {variant} off'))
            lines.setdefault(label, []).append((c.loss, 100 * v.mean(), 100 * low, 100 * high))
        for label, pts in sorted(lines.items()):
            x, y, lo, hi = np.array(sorted(pts)).T
            ax.errorbar(x, y, yerr=[y - lo, hi - y], marker='o', capsize=3, lw=1.4, label=label)
        plots.finish(ax, 'loss (share of states lost on top of delivery)', 'usable graph connected after convergence (%)',
                     f'{kind}: {len({r["layout"] for r in rows if r["kind"] == kind})} layouts')
    return plots.save(fig, path)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument('--layouts', type=int, default=30, help='random layouts (default: 30)')
    ap.add_argument('--seeds', type=int, default=1, help='seeds per layout (default: 1)')
    ap.add_argument('--kinds', default='static,drift2', help=f'comma-separated, of: {", ".join(KINDS)}')
    ap.add_argument('--channels', default=','.join(CHANNELS),
                    help='comma-separated; grid: the 16 of loss 0-0.6 x disc, alpha x latency 0, 3 '
                         f'(default: {",".join(CHANNELS)})')
    ap.add_argument('--variants', default='all', help='comma-separated: all, or rules off joined by + (default: all)')
    ap.add_argument('--workers', type=int, default=os.cpu_count() or 1, help='processes (default: one a core)')
    ap.add_argument('--csv', default='links.csv', help='one row per run, kept across calls (default: links.csv)')
    ap.add_argument('--table', action='store_true', help='only print the table of what --csv holds')
    ap.add_argument('--plot', metavar='PNG', help='also draw the usable graph connected against loss, per kind')
    args = ap.parse_args()
    kinds = [k for k in args.kinds.split(',') if k]
    names = [n for c in args.channels.split(',') if c for n in (GRID if c == 'grid' else (c,))]
    if not kinds or any(k not in KINDS for k in kinds):
        ap.error(f'--kinds: choose from {", ".join(KINDS)}')
    try:
        [channel(c) for c in names]
    except ValueError as exc:
        ap.error(f'--channels: {exc}')
    variants = [v for v in args.variants.split(',') if v]
    unknown = sorted(set().union(*map(off, variants)) - set(ablation.RULES))
    if not variants or unknown:
        ap.error(f'--variants: {", ".join(unknown) or "none"}: not a rule of core/ablation.py')
    done = resumable.rows(args.csv)
    if not args.table:
        done = sweep(args, kinds, names, variants, done)
    print(table(done))
    if args.plot:
        print(f'plot: {against_loss(done, Path(args.plot))}')
    return 0


def sweep(args: argparse.Namespace, kinds: list[str], names: list[str], variants: list[str],
          done: list[dict[str, str]]) -> list[dict[str, str]]:
    have = {(r['variant'], r['kind'], r['channel'], int(r['layout']), int(r['seed'])) for r in done}
    flock = policy_sets(load_scenario('paper'))['default']
    jobs = []
    for n, lay in enumerate(draw('paper', args.layouts, (3, 6), 0, 'ideal')):
        lay = dataclasses.replace(lay, flock=flock)
        for seed in range(args.seeds):
            for kind in kinds:
                jobs += [(v, kind, c, n, seed, scenario_of(kind, n, lay, seed, c)[0]) for c in names for v in variants
                         if (v, kind, c, n, seed) not in have and acts(v, c)]
    return resumable.sweep(args.csv, ['variant', 'kind', 'channel', 'layout', 'seed', *FIELDS], jobs, run, args.workers, done)


if __name__ == '__main__':
    raise SystemExit(main())
