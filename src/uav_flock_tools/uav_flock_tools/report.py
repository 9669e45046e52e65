"""`./uav-flock report BAG`: the paper's plots and a summary table from any bag of a run."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import numpy as np

from world_sim.core import records

from . import bag, plots


def _seconds(v: Optional[float]) -> str:
    return 'not reached' if v is None else f'{v:.1f} s'


def _missing(missing: Optional[dict[int, list[int]]]) -> str:
    if missing is None:
        return 'not known (realtime run)'
    if not missing:
        return 'none: the bag is complete'
    steps = sorted(missing)
    shown = ', '.join(f'step {k}: MAPs {missing[k]}' for k in steps[:5]) + (' ...' if len(steps) > 5 else '')
    return f'{sum(map(len, missing.values()))} at {len(steps)} steps ({shown})'


def summary_table(s: dict[str, Any]) -> str:
    """The summary as a Markdown table (what `report` prints and writes to summary.md)."""
    failures = '; '.join(f'MAP{"s" if len(f["ids"]) > 1 else ""} {", ".join(map(str, f["ids"]))} at t = {f["t_s"]:.1f} s '
                         f'({f["cause"]})' for f in s['failures'])
    rows = [
        ('simulated time', f'{s["duration_s"]:.1f} s ({s["steps"]} steps)'),
        ('MAPs at start / end', f'{s["maps_start"]} / {s["maps_end"]}'),
        ('final coverage R_c', f'{100 * s["final_coverage"]:.1f} %'),
        ('final Fiedler value λ2', f'{s["final_fiedler"]:.4f}'),
        ('time to success: first t with R_c ≥ 95 % and λ2 > 0', _seconds(s['time_to_success_s'])),
        ('R_c ≥ 95 % held to the end, from', _seconds(s['time_to_95_coverage_s'])),
        ('λ2 > 0 held to the end, from', _seconds(s['time_to_connectivity_s'])),
        ('failures', failures or 'none'),
        ('commands used and not recorded', _missing(s['missing_commands'])),
    ]
    width = max(len(k) for k, _ in rows)
    lines = [f'| {"figure".ljust(width)} | value |', f'|{"-" * (width + 2)}|-------|']
    lines += [f'| {k.ljust(width)} | {v} |' for k, v in rows]
    return '\n'.join(lines)


def report(path: Path, out: Path) -> tuple[dict[str, Any], list[Path]]:
    """Read the bag, write the PNGs and summary.md into out; returns the summary and the files."""
    run = bag.load(path)
    s = bag.summary(run)  # raises BagError for a bag without /metrics
    out.mkdir(parents=True, exist_ok=True)
    name = path.resolve().parent.name if path.name == 'bag' else path.name  # RUN/bag: the run's name
    label = f'{s["maps_start"]} MAPs, {name}'
    traj = records.columns(run.trajectory)
    u = run.users
    moving = None
    if len(run.users_at) > 1:  # users that move: each snapshot draws them where they were then
        def moving(t: float) -> tuple[np.ndarray, np.ndarray]:
            now = run.users_of(int(round(t / run.dt)))
            return now.xyz[:, :2], now.cluster
    files = plots.run_figures(run.metrics, traj, None if u is None else u.xyz[:, :2], None if u is None else u.cluster,
                              None if u is None else u.centroids, run.r, label, out,
                              sorted({f['t_s'] for f in s['failures']}), moving)
    (out / 'summary.md').write_text(f'# Run recorded in {path}\n\n{summary_table(s)}\n')
    return s, files + [out / 'summary.md']
