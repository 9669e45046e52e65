"""`./uav-flock report BAG`: the paper's plots and a summary table from any bag of a run."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Iterator, Optional

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
    planned = s.get('planned_duration_s')
    cut = planned is not None and s['duration_s'] < planned - 1e-6
    scheduled = s.get('scheduled_failure')
    if not failures and scheduled is not None and scheduled['t_s'] is not None:
        after = cut and scheduled['t_s'] >= s['duration_s']
        failures = (f'none: {100 * scheduled["fraction"]:g} % of the MAPs were to fail at t = {scheduled["t_s"]:g} s, '
                    + ('after the run was cut short' if after else 'but no MAP was dropped'))
    rows = [
        ('simulated time', f'{s["duration_s"]:.1f} s ({s["steps"]} steps)'
         + (f', INTERRUPTED: the run was to last {planned:g} s' if cut else '')),
        ('MAPs at start / end', f'{s["maps_start"]} / {s["maps_end"]}'),
        ('final coverage R_c', f'{100 * s["final_coverage"]:.1f} %'),
        ('final Fiedler value λ2', f'{s["final_fiedler"]:.4f}'),
        ('time to success: first t with R_c ≥ 95 % and one network (λ2 > 0)', _seconds(s['time_to_success_s'])),
        ('R_c ≥ 95 % held to the end, from', _seconds(s['time_to_95_coverage_s'])),
        ('one network (λ2 > 0) held to the end, from', _seconds(s['time_to_connectivity_s'])),
        ('vehicle', s.get('vehicle') or 'not recorded (a bag from before the vehicle was)'),
        *[(k, v) for k, v in (s.get('flight') or {}).items()],
        ('failures', failures or 'none'),
        ('commands used and not recorded', _missing(s['missing_commands'])),
    ]
    heard = s.get('channel')
    if heard:  # a run under a channel between MAPs (docs/scenarios.md, `links`)
        rows += [('usable graph connected (delivery ≥ 0.5)', f'{100 * heard["usable_connected"]:.1f} % of the steps'),
                 ('heard graph connected (last 1 s)', f'{100 * heard["heard_connected"]:.1f} % of the steps'),
                 ('neighbour states heard', f'{100 * heard["heard_share"]:.1f} %, the oldest used '
                                            f'{heard["oldest_used"]} steps old')]
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
    s['vehicle'] = run.scenario.get('vehicle')
    least, power = (records.vehicle_column(run.metrics, c) for c in ('min_distance', 'power'))
    if least is not None and power is not None:  # a multirotor's /metrics (VehicleMetrics)
        energy = records.vehicle_column(run.metrics, 'energy')
        s['flight'] = {'least distance between two MAPs': f'{float(np.min(least)):.2f} m',
                       'mean power of a MAP': f'{float(np.mean(power)):.1f} W',
                       'energy drawn by the formation': f'{float(energy[-1]) / 1e3:.1f} kJ'}
    label = f'{s["maps_start"]} MAPs, {name}' + (f', {s["vehicle"]}' if s['vehicle'] else '')
    traj = records.columns(run.trajectory)
    u = run.users
    moving = None
    if len(run.users_at) > 1:  # users that move: each snapshot draws them where they were then
        def moving(t: float) -> tuple[np.ndarray, np.ndarray]:
            now = run.users_of(int(round(t / run.dt)))
            return now.xyz[:, :2], now.cluster
    files = plots.run_figures(run.metrics, traj, None if u is None else u.xyz[:, :2], None if u is None else u.cluster,
                              None if u is None else u.centroids, run.r, label, out,
                              sorted({f['t_s'] for f in s['failures']}), moving,
                              separation=run.scenario.get('separation') if s.get('flight') else None)
    (out / 'summary.md').write_text(f'# Run recorded in {path}\n\n{summary_table(s)}\n')
    return s, files + [out / 'summary.md', write_scene(run, traj, out / 'scene.mcap')]


def write_scene(run: bag.BagRun, traj: dict[str, np.ndarray], path: Path) -> Path:
    """scene.mcap: the recorded run in Foxglove's schemas (scene.py), one frame per recorded step, so that it
    opens in Foxglove or Lichtblick with the 3-D scene and the plots and nothing else to set up."""
    from . import scene
    return scene.write_mcap(path, scene_frames(run, traj))


def scene_frames(run: bag.BagRun, traj: dict[str, np.ndarray]) -> Iterator[tuple[float, Any, Optional[dict], list]]:
    """The recorded run as scene frames (t, SceneUpdate, metrics, log entries), one per recorded step: what
    scene.mcap holds and `view` plays."""
    from world_sim.core.physics import label_centroids, survey_radii

    from . import scene

    figures = {int(row[0]): row for row in run.metrics}
    lost = {step: ids for step, ids, _ in run.failures}
    flying: set[int] = set()
    snapshot, centroids, radii = None, None, None  # the users' snapshot the discs were drawn from, and the discs
    for k in np.unique(traj['step']).astype(int).tolist():
        rows = traj['step'] == k
        ids = traj['id'][rows].astype(int).tolist()
        gone, flying = flying - set(ids), set(ids)
        t = float(traj['t'][rows][0])
        users = run.users_of(k)
        if users is not None and users.xyz is not snapshot:  # users are published a survey apart, not each step
            snapshot, found = users.xyz, label_centroids(users.xyz[:, :2], users.cluster)
            # A cluster that arrived during the run has a label beyond the clusters drawn at the start.
            centroids = np.zeros((max(len(users.centroids), max(found, default=-1) + 1), 2))
            for c, at in found.items():
                centroids[c] = at
            radii = survey_radii(users.xyz[:, :2], users.cluster, centroids)
        q = np.column_stack([traj['x'][rows], traj['y'][rows], traj['z'][rows]])
        m = figures.get(k)
        logs = [scene.event(t, f'MAP {i} lost') for i in lost.get(k, [])]
        yield (t, scene.formation(t, ids, q, traj['mode'][rows].astype(int).tolist(), run.r, centroids, radii,
                                  sorted(gone)),
               None if m is None else scene.metrics(m), logs)
