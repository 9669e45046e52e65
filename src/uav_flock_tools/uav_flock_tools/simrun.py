"""Batch runs for the command line: one scenario per (MAP count, seed), outputs and plots per run."""
from __future__ import annotations

import os
import signal
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Callable, Iterable, Optional

import numpy as np

from uav_flock_tools.batch import BatchSimulator
from world_sim.core.model import RunResult
from world_sim.core import outcome, records
from uav_agent.core.links import describe
from world_sim.core.crowd import events as events_of
from world_sim.core.hearing import LINK_COLUMNS
from world_sim.core.scenario import Scenario
from world_sim.shipped import load_scenario  # noqa: F401 (the CLI, paper and benchmarks read it here)

from . import plots


def trajectory_columns(result: RunResult) -> dict[str, np.ndarray]:
    return records.columns(result.trajectory)


def write_run(result: RunResult, folder: Path, label: str, pictures: bool = True) -> list[Path]:
    """metrics.csv, trajectory.csv, the MSDs and failures, and (with pictures) the run's figures into folder;
    their titles name the scenario and the label."""
    folder.mkdir(parents=True, exist_ok=True)
    records.write_metrics(folder / 'metrics.csv', result.metrics)
    records.write_trajectory(folder / 'trajectory.csv', result.trajectory)
    records.write_users(folder / records.USERS_FILE, result.users, result.motion)
    records.write_failures(folder / records.FAILURES_FILE, result.failed, result.fail_step, result.events)
    if not pictures:
        return []
    events: list[plots.Event] = \
        [result.fail_step * result.scenario.dt] if result.fail_step is not None and len(result.failed) else []
    u, dt = result.users, result.scenario.dt
    events += [(step * dt, f'{len(ids)} MAP{"s" if len(ids) > 1 else ""} {cause}') for step, ids, cause in result.events
               if cause != 'scheduled']  # killed by hand (the scheduled failure is marked above)
    end = float(result.metrics[-1, 1]) if len(result.metrics) else 0.0
    if end < result.scenario.duration - dt / 2:  # Ctrl-C, or world_sim ended early: every picture says so
        events.append((end, 'run interrupted'))
        label = f'{label}, interrupted at t = {end:.1f} s'
    moving = None if result.motion is None else (lambda t: result.motion.at(int(round(t / dt))))
    radio = None if result.scenario.links.perfect else describe(result.scenario.links)
    return plots.run_figures(result.metrics, trajectory_columns(result), u.xyz[:, :2], u.cluster, u.centroids,
                             result.scenario.flock.r, f'{result.scenario.name} ({result.scenario.vehicle.model}), {label}',
                             folder,
                             [*events, *events_of(result.scenario)], moving, radio,
                             None if result.scenario.vehicle.ideal else result.scenario.vehicle.separation)


def simulate(scenario: Scenario, progress: Optional[Callable[[int], None]] = None) -> tuple[RunResult, bool]:
    """Run to the end; on Ctrl-C keep what was simulated and say it is partial."""
    sim = BatchSimulator(scenario)
    try:
        return sim.run(progress), True
    except KeyboardInterrupt:
        return sim.result(), False


def metrics_only(scenario: Scenario) -> np.ndarray:
    """Worker for parallel sweeps: the metrics rows of one run."""
    return BatchSimulator(scenario).run().metrics


def sweep(scenarios: list[Scenario], on_done: Callable[[], None], workers: int | None = None
          ) -> list[np.ndarray]:
    """Metrics of many runs, in parallel over the machine's cores, in input order."""
    workers = workers or max(1, min(len(scenarios), os.cpu_count() or 1))
    if workers == 1:
        out = []
        for s in scenarios:
            out.append(metrics_only(s))
            on_done()
        return out
    # The workers leave Ctrl-C to this process. Here it cancels the runs not yet started; a worker would
    # otherwise report its run as interrupted and go on with the next, and the pool would wait for them all.
    with ProcessPoolExecutor(max_workers=workers, initializer=signal.signal,
                             initargs=(signal.SIGINT, signal.SIG_IGN)) as pool:
        futures = [pool.submit(metrics_only, s) for s in scenarios]
        results = []
        try:
            for f in futures:
                results.append(f.result())
                on_done()
        except BaseException:
            pool.shutdown(wait=True, cancel_futures=True)
            raise
        return results


def grid(base: Scenario, maps: Iterable[int], seeds: Iterable[int], **overrides: object) -> list[Scenario]:
    return [base.with_overrides(maps=n, seed=k, **overrides) for n in maps for k in seeds]


SUMMARY_FILE = 'summary.csv'


def write_summary(results: list[RunResult], out: Path) -> list[str]:
    """A sweep's summary.csv (one row per run: its final values and time to success) and, returned, a table of
    mean ± std over the seeds of each MAP count."""
    rows = ['maps,seed,final_coverage,final_fiedler,components,alive,time_to_success_s']
    by_maps: dict[int, list[list[float]]] = {}
    for r in results:
        m = r.metrics
        t = outcome.time_to_success(m)
        values = [float(m[-1, 2]), float(m[-1, 3]), float(m[-1, 5]), float(m[-1, 4]), t]
        rows.append(f'{r.scenario.maps},{r.scenario.seed},{values[0]:.6f},{values[1]:.6f},{int(values[2])},'
                    f'{int(values[3])},{"" if not np.isfinite(t) else f"{t:.1f}"}')
        by_maps.setdefault(r.scenario.maps, []).append(values)
    (out / SUMMARY_FILE).write_text('\n'.join(rows) + '\n')
    table = ['| MAPs | runs | final R_c | final λ2 | components | time to success (runs reaching it) |',
             '|---|---|---|---|---|---|']
    for maps, v in sorted(by_maps.items()):
        a = np.array(v)
        reached = a[np.isfinite(a[:, 4]), 4]
        spread = f' ± {reached.std():.1f}' if len(reached) > 1 else ''  # no spread of a single run
        success = f'{reached.mean():.1f}{spread} s ({len(reached)}/{len(a)})' if len(reached) else f'never (0/{len(a)})'
        table.append(f'| {maps} | {len(a)} | {100 * a[:, 0].mean():.1f} ± {100 * a[:, 0].std():.1f} % | '
                     f'{a[:, 1].mean():.4f} ± {a[:, 1].std():.4f} | {a[:, 2].mean():.1f} ± {a[:, 2].std():.1f} | '
                     f'{success} |')
    return table


def read_run(run: Path, scenario: Scenario) -> Optional[RunResult]:
    """The run's records as a RunResult, from the files world_sim wrote (None if it wrote none)."""
    if not all((run / f).exists() for f in ('metrics.csv', 'trajectory.csv', records.USERS_FILE,
                                            records.FAILURES_FILE)):
        return None
    m = records.read_csv(run / 'metrics.csv')
    if len(m['step']) == 0:
        return None
    t = records.read_trajectory(run)
    metrics = records.rows(m, tuple(c for c in records.METRICS_COLUMNS + LINK_COLUMNS + records.VEHICLE_COLUMNS if c in m))
    traj = records.rows(t, tuple(c for c in records.TRAJECTORY_COLUMNS + records.ESTIMATE_COLUMNS if c in t))
    failed, fail_step, events = records.read_failures(run / records.FAILURES_FILE)
    return RunResult(scenario, records.read_users(run / records.USERS_FILE), metrics, traj, failed, fail_step,
                     records.read_motion(run / records.USERS_FILE), events)
