"""What a study's table says: per cell (kind x variant) the figures' mean, 10th percentile, worst and a
bootstrap 95 % interval; each variant against the first, paired by run; a strip plot of the runs."""
from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np

FIGURE = 'connected'  # the share of time connected after convergence (0 for a run that never converged)


def interval(d: np.ndarray) -> tuple[float, float]:
    """The bootstrap 95 % interval of the mean of d (scipy.stats.bootstrap); the mean itself when d does not
    vary. The one interval uav-flock puts on a mean over runs (the study's summary and the benchmarks)."""
    if len(d) < 2 or np.all(d == d[0]):
        return float(np.mean(d)), float(np.mean(d))
    from scipy.stats import bootstrap
    ci = bootstrap((d,), np.mean, confidence_level=0.95, n_resamples=4000, random_state=0).confidence_interval
    return float(ci.low), float(ci.high)


def _value(r: dict[str, Any]) -> float:
    return float(r[FIGURE]) if r.get(FIGURE) is not None else 0.0


def cells(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One line per (kind, variant), in the order they first appear; paired change against the first variant."""
    kinds = list(dict.fromkeys(r['kind'] for r in rows))
    variants = list(dict.fromkeys(r['variant'] for r in rows))
    by = {(r['kind'], r['variant'], r['layout'], r['seed']): r for r in rows}
    out = []
    for kind in kinds:
        for variant in variants:
            cell = [r for r in rows if r['kind'] == kind and r['variant'] == variant]
            if not cell:
                continue
            v = np.array([_value(r) for r in cell])
            lo, hi = interval(v)
            line = {'kind': kind, 'variant': variant, 'runs': len(cell), 'errors': sum(r['error'] is not None for r in cell),
                    'converged': sum(r['converged'] is not None for r in cell), 'unsplit': _unsplit(cell),
                    'mean': v.mean(), 'low': lo, 'high': hi,
                    'p10': float(np.percentile(v, 10)), 'worst': float(v.min()),
                    'ends_ok': int(sum(r['ends_ok'] or 0 for r in cell)), 'disc': _disc(cell),
                    'change': None, 'change_low': None, 'change_high': None}
            if variant != variants[0]:
                pairs = [(_value(r), _value(by[(kind, variants[0], r['layout'], r['seed'])])) for r in cell
                         if (kind, variants[0], r['layout'], r['seed']) in by]
                if pairs:
                    d = np.array([a - b for a, b in pairs])
                    line['change'], (line['change_low'], line['change_high']) = float(d.mean()), interval(d)
            out.append(line)
    return out


def _unsplit(cell: list[dict[str, Any]]) -> Any:
    """The runs that converged and never split after it (the issue's "never splits it"); None for a table from
    before the column."""
    if any(r.get('splits') is None and r.get('converged') is not None for r in cell):
        return None
    return sum(r['converged'] is not None and r['splits'] == 0 for r in cell)


def _disc(cell: list[dict[str, Any]]) -> Any:
    """The disc graph's mean share connected after convergence (0 for a run that never converged); None for a
    table from before the column."""
    if any(r.get('disc') is None and r.get('converged') is not None for r in cell):
        return None
    return float(np.mean([r['disc'] or 0.0 for r in cell]))


def _pct(x: Any) -> str:
    return '—' if x is None else f'{100 * x:.1f}'


def markdown(lines: list[dict[str, Any]], base: str) -> str:
    head = ('| kind | variant | runs | converged | never split after it | connected after convergence: mean [95 %] | '
            f'10th pct | worst | ends covered and connected | disc graph connected: mean | change against {base}, paired '
            '[95 %] |\n' + '|---' * 11 + '|')
    body = [f"| {c['kind']} | {c['variant']} | {c['runs']}{' (' + str(c['errors']) + ' errors)' if c['errors'] else ''} | "
            f"{c['converged']}/{c['runs']} | {'—' if c['unsplit'] is None else c['unsplit']} | "
            f"{_pct(c['mean'])} [{_pct(c['low'])}, {_pct(c['high'])}] | {_pct(c['p10'])} | "
            f"{_pct(c['worst'])} | {c['ends_ok']}/{c['runs']} | {_pct(c['disc'])} | "
            + ('' if c['change'] is None else f"{100 * c['change']:+.2f} [{100 * c['change_low']:+.2f}, {100 * c['change_high']:+.2f}]")
            + ' |' for c in lines]
    return '\n'.join([head, *body]) + '\n'


def flight(rows: list[dict[str, Any]]) -> str:
    """A multirotor's lines (docs/vehicle.md): time to success against T*, least distance, the envelope as flown,
    power after convergence against hover; '' when no run flew one."""
    if not any(r.get('t_star') is not None for r in rows):
        return ''
    from world_sim.core.vehicle import HOVER
    out = ['| kind | variant | converged / T*: median | worst | least distance (m) | top speed (m/s) | '
           'top acceleration (m/s²) | power after convergence / hover: mean | worst | MAP-steps a protected link '
           'gave way, held back (filter) | longest a MAP held back from its goal (s), MAP-steps set free (rule release) | '
           'connected once formed: mean, worst (runs formed) |', '|---' * 12 + '|']
    for kind in dict.fromkeys(r['kind'] for r in rows):
        for variant in dict.fromkeys(r['variant'] for r in rows):
            cell = [r for r in rows if r['kind'] == kind and r['variant'] == variant and r.get('t_star') is not None]
            if not cell:
                continue
            ratio = np.array([r['converged'] / r['t_star'] if r['converged'] is not None else np.inf for r in cell])
            power = np.array([r['power'] / HOVER for r in cell])
            out.append(f"| {kind} | {variant} | {np.median(ratio):.2f} | {ratio.max():.2f} | "
                       f"{min(r['least_distance'] for r in cell):.2f} | {max(r['top_speed'] for r in cell):.2f} | "
                       f"{max(r['top_accel'] for r in cell):.2f} | {power.mean():.3f} | {power.max():.3f} | "
                       f"{_shares(cell)} | {_liveness(cell)} | {_formed(cell)} |")
    return '\n## Flight (multirotor)\n\n' + '\n'.join(out) + '\n'


def _formed(cell: list[dict[str, Any]]) -> str:
    """The share of time connected once the formation was formed (cases.FORMED_SPEED), over a cell's runs that
    formed ('' for runs flown before it was counted)."""
    if any('connected_formed' not in r for r in cell):
        return ''
    shares = [x for x in (r['connected_formed'] for r in cell) if x is not None and np.isfinite(x)]
    return f'{_pct(np.mean(shares))} %, {_pct(min(shares))} % ({len(shares)})' if shares else '— (0)'


def _shares(cell: list[dict[str, Any]]) -> str:
    """The filter's relaxed and held shares of MAP-steps over a cell's runs, as percentages ('' for runs flown
    before they were counted)."""
    if any(r.get('relaxed') is None for r in cell):
        return ''
    return f"{100 * np.mean([r['relaxed'] for r in cell]):.2f} %, {100 * np.mean([r['held'] for r in cell]):.2f} %"


def _liveness(cell: list[dict[str, Any]]) -> str:
    """Rule 'release' over a cell's runs: the longest any MAP was held back from its goal without a break, and the
    share of MAP-steps free of their links ('' for runs flown before they were counted, or without the filter)."""
    if any(r.get('held_longest') is None for r in cell):
        return ''
    return f"{max(r['held_longest'] for r in cell):.1f}, {100 * np.mean([r['released'] for r in cell]):.2f} %"


def write(rows: list[dict[str, Any]], out: Path) -> list[Path]:
    """summary.md, summary.csv and connected.png beside the table."""
    lines = cells(rows)
    base = lines[0]['variant'] if lines else ''
    (out / 'summary.md').write_text(f'# Study: {len(rows)} runs\n\n"Connected" is the share of time lambda2 > 0 after the '
                                    'first step covered (R_c >= 95 %) and connected, 0 for a run that never got there; under a links: channel, '
                                    'of the usable graph (docs/links.md).\n\n'
                                    + markdown(lines, base) + flight(rows))
    with open(out / 'summary.csv', 'w', newline='') as f:
        w = csv.DictWriter(f, fieldnames=list(lines[0]) if lines else ['kind'])
        w.writeheader()
        w.writerows(lines)
    return [out / 'summary.md', out / 'summary.csv', strip_plot(rows, lines, out / 'connected.png')]


def strip_plot(rows: list[dict[str, Any]], lines: list[dict[str, Any]], path: Path) -> Path:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(max(6.4, 1.2 * len(lines) + 1), 4.4))
    rng = np.random.default_rng(0)
    for x, c in enumerate(lines):
        v = np.array([_value(r) for r in rows if r['kind'] == c['kind'] and r['variant'] == c['variant']]) * 100
        ax.scatter(x + rng.uniform(-0.15, 0.15, len(v)), v, s=12, alpha=0.6)
        ax.errorbar(x, 100 * c['mean'], yerr=[[100 * (c['mean'] - c['low'])], [100 * (c['high'] - c['mean'])]],
                    fmt='_', color='k', capsize=6, markersize=20)
    ax.set_xticks(range(len(lines)), [f"{c['kind']}\n{c['variant']}" for c in lines], fontsize=8)
    ax.set_xlim(-0.6, len(lines) - 0.4)
    ax.set_ylim(-3.0, 103.0)  # a share: the whole scale, so that studies compare at a glance
    ax.set_ylabel('connected after convergence (%)')
    ax.set_title(f'Study {path.parent.name}: {len(rows)} runs\n'
                 'dots: each run; bar: the mean with its 95 % interval', fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
