"""Regenerate the paper's figures over several seeds and write docs/results.md beside the paper's claims."""
from __future__ import annotations

import dataclasses
import re
import time
from pathlib import Path
from typing import Callable

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from uav_agent.core.policies import ALLOCATIONS, DEFAULT  # noqa: E402
from world_sim.core import outcome  # noqa: E402
from world_sim.core.scenario import Scenario  # noqa: E402

from . import layouts, plots, simrun  # noqa: E402

COUNTS_FIG = (40, 60, 80, 100)
COUNTS_SWEEP = tuple(range(40, 121, 10))
COUNTS_DEMAND = tuple(range(40, 91, 5))  # the demand allocation connects at fewer MAPs: a finer sweep
LAYOUT_FACTORS = (1.2, 1.5, 2.0)          # MAPs as multiples of a random layout's floor LB
LAYOUT_DURATION = 90.0
FAIL_FRACTIONS = (0.1, 0.2, 0.3, 0.4, 0.5)
FAIL_AT = 18.0
SETTLE = 10.0  # "after convergence": the mean over the last SETTLE seconds of a run



def settled(m: np.ndarray, column: int) -> float:
    t = m[:, 1]
    return float(np.mean(m[t >= t[-1] - SETTLE, column]))


def time_to_connected_coverage(m: np.ndarray) -> float:
    """outcome.time_to_success, NaN if never (the tables average over the seeds that reach it)."""
    t = outcome.time_to_success(m)
    return t if np.isfinite(t) else float('nan')


def _band(ax: plt.Axes, runs: list[np.ndarray], column: int, scale: float, label: str, since: float = 0.0) -> None:
    """Mean and min-max band over seeds, from `since` on (a failure run equals the run without one before it)."""
    t = runs[0][:, 1]
    y = np.array([r[:, column] for r in runs]) * scale
    shown = t >= since - 1e-9
    t, y = t[shown], y[:, shown]
    ax.plot(t, y.mean(axis=0), lw=1.6, label=label)
    ax.fill_between(t, y.min(axis=0), y.max(axis=0), alpha=0.2)


def _figure(path: Path, groups: list[tuple[str, list[np.ndarray]]], column: int, scale: float,
            ylabel: str, title: str, events: tuple[float, ...] = (), since: tuple[float, ...] = ()) -> Path:
    """since: per group, the time its curve starts (default 0)."""
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for i, (label, runs) in enumerate(groups):
        _band(ax, runs, column, scale, label, since[i] if i < len(since) else 0.0)
    if column == 3:  # the Fiedler value: connected or not is what the figure is for
        plots.fiedler_axis(ax)
    plots.finish(ax, 'time t (s)', ylabel, title + ' (line: mean over seeds, band: min to max)', events)
    return plots.save(fig, path)


def _fiedler_vs_count(path: Path, counts: tuple[int, ...], values: dict[int, list[float]],
                      policies: str = "the paper's Algorithm 2") -> Path:
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    mean = [np.mean(values[n]) for n in counts]
    ax.errorbar(counts, mean, yerr=[np.std(values[n]) for n in counts], marker='o', capsize=3,
                label='mean ± std over seeds')
    for n in counts:
        ax.scatter([n] * len(values[n]), values[n], s=8, c='0.5', zorder=3)
    plots.fiedler_axis(ax)
    plots.finish(ax, 'number of MAPs', f'λ2, mean of the last {SETTLE:g} s (no unit; log above {plots.FIEDLER_LINEAR_BELOW:g})',
                 f'Connectivity after convergence, {policies}\n(grey: single seeds)')
    return plots.save(fig, path)


def _fmt(values: list[float], pct: bool = False, digits: int = 3) -> str:
    v = np.asarray(values, dtype=float) * (100 if pct else 1)
    unit = ' %' if pct else ''
    d = 1 if pct else digits
    return f'{np.nanmean(v):.{d}f} ± {np.nanstd(v):.{d}f}{unit} (min {np.nanmin(v):.{d}f}, max {np.nanmax(v):.{d}f})'


# The open choices and their alternatives, measured against the scenario's own setting.
def ablation_variants(base: Scenario) -> list[tuple[str, Scenario]]:
    f = base.flock
    out = [('scenario as shipped', base)]
    for name in ALLOCATIONS:
        if name != f.allocation:
            out.append((f'policies.allocation = {name}' + (' (the default)' if name == DEFAULT else ''),
                        dataclasses.replace(base, flock=dataclasses.replace(f, allocation=name))))
    for key, value in (('zero_users', 'static'), ('m1_pending', 'lead'), ('m0_exhausted', 'serve'),
                       ('edge_choice', 'nearest'), ('edge_choice', 'keep_nearest'), ('edge_choice', 'share')):
        if getattr(f, key) != value:
            out.append((f'policies.{key} = {value}', dataclasses.replace(base, flock=dataclasses.replace(f, **{key: value}))))
    for g in (0.1, 0.35):
        out.append((f'flock.gamma = {g}', dataclasses.replace(base, flock=dataclasses.replace(f, gamma=g))))
    other = 'horizontal' if base.association == '3d' else '3d'
    out.append((f'radio.association = {other}', dataclasses.replace(base, association=other)))
    return out


def with_demand(s: Scenario) -> Scenario:
    """The scenario under the default policies: what it runs with its `policies` left out."""
    return dataclasses.replace(s, flock=layouts.policy_sets(s)['default'])


def main(seeds: int, out: Path, docs: Path, scenario: str, ablation: bool = True, random_layouts: int = 20,
         command: str = '') -> int:
    """command: the command line that ran, which results.md names as its provenance."""
    base = simrun.load_scenario(scenario)
    seed_ids = list(range(seeds))
    out.mkdir(parents=True, exist_ok=True)
    started = time.time()

    jobs: list[tuple[str, Scenario]] = []
    jobs += [(f'sweep/{n}/{k}', base.with_overrides(maps=n, seed=k)) for n in COUNTS_SWEEP for k in seed_ids]
    jobs += [(f'fail/{fr}/{k}', base.with_overrides(maps=80, seed=k, fail_at=FAIL_AT, fail_fraction=fr))
             for fr in FAIL_FRACTIONS for k in seed_ids]
    variants = ablation_variants(base) if ablation else []
    jobs += [(f'abl/{i}/{n}/{k}', s.with_overrides(maps=n, seed=k))
             for i, (_, s) in enumerate(variants) for n in (60, 80, 90) for k in seed_ids]
    demand = with_demand(base)
    jobs += [(f'demand/{n}/{k}', demand.with_overrides(maps=n, seed=k)) for n in COUNTS_DEMAND for k in seed_ids]
    with tqdm(total=len(jobs), unit='run', desc='paper runs', mininterval=0.5) as bar:
        metrics = dict(zip((name for name, _ in jobs), simrun.sweep([s for _, s in jobs], lambda: bar.update(1))))
    ended: list[layouts.Ended] = []
    if random_layouts:
        with tqdm(total=random_layouts * len(LAYOUT_FACTORS) * 2, unit='run', desc='random layouts',
                  mininterval=0.5) as bar:
            ended = layouts.evaluate(base, random_layouts, 1, list(LAYOUT_FACTORS), ['default', 'paper'],
                                     LAYOUT_DURATION, 0, lambda done, total: bar.update(1))

    def runs(prefix: str) -> list[np.ndarray]:
        return [metrics[f'{prefix}/{k}'] for k in seed_ids]

    figs: dict[str, Path] = {}
    figs['coverage'] = _figure(out / 'coverage_vs_time.png', [(f'{n} MAPs', runs(f'sweep/{n}')) for n in COUNTS_FIG],
                               2, 100, 'coverage ratio R_c (%)', 'Coverage vs time')
    figs['fiedler'] = _figure(out / 'fiedler_vs_time.png', [(f'{n} MAPs', runs(f'sweep/{n}')) for n in COUNTS_FIG],
                              3, 1, plots.FIEDLER_LABEL, 'Fiedler value vs time')
    figs['failures'] = _figure(out / 'coverage_failures.png',
                               [('no failure', runs('sweep/80'))]
                               + [(f'{int(fr * 100)} % fail', runs(f'fail/{fr}')) for fr in FAIL_FRACTIONS],
                               2, 100, 'coverage ratio R_c (%)', '80 MAPs, random failures', (FAIL_AT,),
                               since=(0.0,) + (FAIL_AT,) * len(FAIL_FRACTIONS))  # all one curve before it
    settled_f = {n: [settled(m, 3) for m in runs(f'sweep/{n}')] for n in COUNTS_SWEEP}
    figs['fiedler_count'] = _fiedler_vs_count(out / 'fiedler_vs_maps.png', COUNTS_SWEEP, settled_f)
    snap = base.with_overrides(maps=90, seed=0)
    result, _ = simrun.simulate(snap)
    figs['formation'] = plots.formation_snapshots(
        simrun.trajectory_columns(result), result.users.xyz[:, :2], result.users.cluster, result.users.centroids,
        snap.flock.r, (0.0, 10.0, 20.0, 30.0), '90 MAPs, seed 0', out / 'formation_90.png')

    settled_d = {n: [settled(m, 3) for m in runs(f'demand/{n}')] for n in COUNTS_DEMAND}
    figs['fiedler_count_demand'] = _fiedler_vs_count(out / 'fiedler_vs_maps_demand.png', COUNTS_DEMAND, settled_d,
                                                     'demand allocation')
    write_results(docs, out, base, seeds, metrics, seed_ids, settled_f, variants, figs, time.time() - started,
                  settled_d, ended, command or f'./uav-flock paper --seeds {seeds}')
    print(f'figures in {out}, results in {docs} ({time.time() - started:.0f} s)')
    return 0


Runs = Callable[[str], list[np.ndarray]]


def write_results(docs: Path, out: Path, base: Scenario, seeds: int, metrics: dict[str, np.ndarray],
                  seed_ids: list[int], settled_f: dict[int, list[float]],
                  variants: list[tuple[str, Scenario]], figs: dict[str, Path], elapsed: float,
                  settled_d: dict[int, list[float]], ended: list[layouts.Ended], command: str) -> None:
    def runs(prefix: str) -> list[np.ndarray]:
        return [metrics[f'{prefix}/{k}'] for k in seed_ids]

    rel = lambda p: Path(p).resolve().relative_to(docs.resolve().parent).as_posix()  # noqa: E731
    lines = _paper_lines(base, command, seed_ids, elapsed, runs, settled_f)
    lines += _figure_lines(figs, rel)
    if variants:
        lines += _ablation_lines(variants, seeds, runs)
    lines += _demand_lines(seeds, runs, settled_d, figs, rel)
    if ended:
        lines += _layout_lines(ended)
    docs.parent.mkdir(parents=True, exist_ok=True)
    carried = _others(docs.read_text(), lines) if docs.exists() else []
    docs.write_text('\n'.join(lines) + '\n' + ''.join('\n' + section for section in carried))


# Every section this command may write (some only when asked): an earlier one left out this time is not kept.
OWN_HEADINGS = ('## Figures', '## Effect of each open choice', '## The demand allocation on the paper layout',
                '## Random layouts')


def _others(text: str, lines: list[str]) -> list[str]:
    """The sections of an earlier results.md that this command does not write (the benchmarks' own, as
    benchmarks/bench_links.py's radio and bench_dynamics.py's moving users), in their order, to be kept."""
    ours = {line for line in lines if line.startswith('## ')} | set(OWN_HEADINGS)
    sections = re.split(r'(?m)^(?=## )', text)[1:]
    return [sec.rstrip('\n') + '\n' for sec in sections if sec.splitlines()[0] not in ours]


def _paper_lines(base: Scenario, command: str, seed_ids: list[int], elapsed: float, runs: Runs,
                 settled_f: dict[int, list[float]]) -> list[str]:
    """The table of the paper's claims beside ours."""
    seeds = len(seed_ids)
    final: Callable[[str, int], list[float]] = lambda prefix, col: [settled(m, col) for m in runs(prefix)]
    t_conn = [time_to_connected_coverage(m) for m in runs('sweep/90')]
    lines = [
        '# Results: the paper beside ours',
        '',
        f'Generated by `{command}` (scenario `{base.name}`, {base.duration:g} s runs, '
        f'Δt = {base.dt:g} s, seeds {seed_ids[0]}–{seed_ids[-1]}) in {elapsed:.0f} s of wall time on this machine.',
        f'"After convergence" is the mean over the last {SETTLE:g} s of a run. Values: mean ± std over seeds '
        '(min, max). The runs are those of the batch simulator, which executes the very per-MAP functions the '
        'agent nodes run.',
        '',
        '| paper | ours |',
        '|---|---|',
        f'| 40 MAPs: coverage ≈ 70 % after convergence | {_fmt(final("sweep/40", 2), pct=True)} |',
        f'| 80 MAPs: coverage > 95 % | {_fmt(final("sweep/80", 2), pct=True)} |',
        f'| 100 MAPs: coverage > 95 %, highest 97.3 % | {_fmt(final("sweep/100", 2), pct=True)} |',
        f'| 40 MAPs: Fiedler value 0 after convergence | {_fmt(settled_f[40], digits=4)} |',
        f'| 60 MAPs: Fiedler value 0 after convergence | {_fmt(settled_f[60], digits=4)} |',
        f'| 80 MAPs: Fiedler value > 0 | {_fmt(settled_f[80], digits=4)}; connected in '
        f'{sum(v > 0 for v in settled_f[80])}/{seeds} seeds |',
        f'| 100 MAPs: Fiedler value > 0, highest 0.021 | {_fmt(settled_f[100], digits=4)}; connected in '
        f'{sum(v > 0 for v in settled_f[100])}/{seeds} seeds |',
        f'| 90 MAPs: connected network covering all four clusters at t = 30 s | first time with λ2 > 0 and '
        f'R_c ≥ 95 %: {", ".join("never" if np.isnan(v) else f"{v:.1f} s" for v in t_conn)}; '
        f'by 30 s in {sum(v <= 30 for v in t_conn if not np.isnan(v))}/{seeds} seeds |',
    ]
    for fr in (0.1, 0.3, 0.5):
        fail_runs = runs(f'fail/{fr}')
        low = [float(np.min(m[m[:, 1] >= FAIL_AT, 2])) for m in fail_runs]
        lines.append(
            f'| 80 MAPs, {int(fr * 100)} % fail at t = 18 s: coverage restored'
            + (', ≈ 85 % with connectivity lost' if fr == 0.5 else '')
            + f' | dip to {_fmt(low, pct=True)}, after convergence {_fmt(final(f"fail/{fr}", 2), pct=True)}; '
            f'connected at the end in {sum(settled(m, 3) > 0 for m in fail_runs)}/{seeds} seeds |')
    zero_below = [n for n in COUNTS_SWEEP if max(settled_f[n]) == 0]
    lines.append(
        '| Fiedler after convergence: 0 below ~65 MAPs, steep rise 65–80, slower rise to 120 | '
        + ', '.join(f'{n}: {np.mean(settled_f[n]):.4f}' for n in COUNTS_SWEEP)
        + (f' (0 in every seed up to {max(zero_below)} MAPs)' if zero_below else '') + ' |')
    return lines


def _figure_lines(figs: dict[str, Path], rel: Callable[[Path], str]) -> list[str]:
    lines: list[str] = []
    lines += [
        '',
        '## Figures',
        '',
        f'![Formation of 90 MAPs]({rel(figs["formation"])})',
        '',
        f'![Coverage vs time]({rel(figs["coverage"])})',
        '',
        f'![Fiedler value vs time]({rel(figs["fiedler"])})',
        '',
        f'![Coverage with failures]({rel(figs["failures"])})',
        '',
        f'![Fiedler value vs MAP count]({rel(figs["fiedler_count"])})',
        '',
    ]
    return lines


def _ablation_lines(variants: list[tuple[str, Scenario]], seeds: int, runs: Runs) -> list[str]:
    """One row per open choice changed from the shipped scenario."""
    lines = [
        '## Effect of each open choice',
        '',
        'Each row changes one choice of `docs/choices.md` from the shipped scenario and reruns 60, 80 and 90 MAPs '
        f'over the same {seeds} seeds. "connected" counts seeds whose Fiedler value after convergence is > 0; '
        '"t95" is the mean first time with λ2 > 0 and R_c ≥ 95 % over the seeds that reach it.',
        '',
        '| variant | 60: R_c, connected | 80: R_c, connected | 90: R_c, connected, t95 |',
        '|---|---|---|---|',
    ]
    for i, (label, _) in enumerate(variants):
        cells = []
        for n in (60, 80, 90):
            ms = runs(f'abl/{i}/{n}')
            rc = np.mean([settled(m, 2) for m in ms]) * 100
            conn = sum(settled(m, 3) > 0 for m in ms)
            cell = f'{rc:.1f} %, {conn}/{seeds}'
            if n == 90:
                t = [time_to_connected_coverage(m) for m in ms]
                reached = [v for v in t if not np.isnan(v)]
                cell += f', {np.mean(reached):.1f} s' if reached else ', never'
            cells.append(cell)
        lines.append(f'| {label} | ' + ' | '.join(cells) + ' |')
    lines.append('')
    return lines


def _demand_lines(seeds: int, runs: Runs, settled_d: dict[int, list[float]], figs: dict[str, Path],
                  rel: Callable[[Path], str]) -> list[str]:
    t_demand = [time_to_connected_coverage(m) for m in runs('demand/90')]
    first_conn = [n for n in COUNTS_DEMAND if min(settled_d[n]) > 0]
    return [
        '## The demand allocation on the paper layout',
        '',
        'The same layout with the default policies (`allocation: demand`, what a scenario without `policies` runs; '
        'docs/allocation.md). Fiedler value after convergence by MAP count, over the same seeds:',
        '',
        '| MAPs | ' + ' | '.join(str(n) for n in COUNTS_DEMAND) + ' |',
        '|---' * (len(COUNTS_DEMAND) + 1) + '|',
        '| λ2 (mean) | ' + ' | '.join(f'{np.mean(settled_d[n]):.4f}' for n in COUNTS_DEMAND) + ' |',
        '| connected seeds | ' + ' | '.join(f'{sum(v > 0 for v in settled_d[n])}/{seeds}' for n in COUNTS_DEMAND)
        + ' |',
        '',
        (f'Connected in every seed from {first_conn[0]} MAPs on' if first_conn else 'Never connected in every seed')
        + ' (Algorithm 2: ~65 in the paper, 70 here). 90 MAPs: first time with λ2 > 0 and R_c ≥ 95 %: '
        f'{", ".join("never" if np.isnan(v) else f"{v:.1f} s" for v in t_demand)}; by 30 s in '
        f'{sum(v <= 30 for v in t_demand if not np.isnan(v))}/{seeds} seeds.',
        '',
        f'![Fiedler value vs MAP count, demand allocation]({rel(figs["fiedler_count_demand"])})',
        '',
    ]


def _layout_lines(ended: list[layouts.Ended]) -> list[str]:
    count = len({e.job.layout for e in ended})
    lines = [
        '## Random layouts',
        '',
        f'{count} layouts of `./uav-flock layouts --seed 0` (3 to 6 clusters, docs/allocation.md), one seed, '
        f'{LAYOUT_DURATION:g} s, N = ceil(factor x LB). Success: R_c ≥ 95 % on average and λ2 > 0 throughout '
        'the last 10 s. `benchmarks/bench_layouts.py` runs more layouts and seeds.',
        '',
    ]
    for policy, title in (('default', 'Default policies (demand allocation)'),
                          ('paper', "The paper's Algorithm 2 (paper.yaml)")):
        lines += [f'**{title}**', '', *layouts.table(ended, policy, list(LAYOUT_FACTORS)), '']
    return lines
