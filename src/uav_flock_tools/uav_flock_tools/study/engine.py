"""A study's runs as Dask tasks, their rows streamed into one Parquet table as they finish.

Each finished run is written at once as its own part (parts/<key>.parquet); the parts are gathered into
results.parquet when the study ends, is interrupted or fails, and the same command again computes only the
runs whose key is in neither. The runs go to a LocalCluster sized to the machine, or to the workers of an
existing scheduler (`dask scheduler`, `dask worker` on any host with uav-flock installed).
"""
from __future__ import annotations

import logging
import os
import signal
import socket
import time
import traceback
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any, Callable, Iterator, Optional

import numpy as np

from .cases import EVENT_S, FIGURES, IN_FLIGHT, wipe_at
from .spec import Run

if TYPE_CHECKING:
    from world_sim.core.scenario import Scenario

    from ..batch import BatchSimulator

RESULTS = 'results.parquet'
PARTS = 'parts'
SERIES = 'series'  # with --keep: series/<key>.parquet, a run's metrics (a column each, a row a step)
GRID = ('key', 'layout', 'seed', 'kind', 'variant', 'maps', 'duration')
# code: the digest of the code that flew the run (provenance.code); wall_s and host: where and how long, not what
COLUMNS = (*GRID, *FIGURES, 'error', 'code', 'wall_s', 'host')


def flight(run: Run, s: Scenario, watch: bool = False) -> Iterator[BatchSimulator]:
    """The run (its scenario s) as a study flies it, the simulator after each step; the last step is recorded
    without moving on. The caller switches off the rules the run's variant does (ablation.switched_off(run.off));
    watch: each step keeps what it decided (BatchSimulator.decided, for `uav-flock trace`)."""
    from ..batch import BatchSimulator
    kind = run.kind.partition(':')[0]
    sim, rng = BatchSimulator(s, watch), np.random.default_rng(run.draw_seed + IN_FLIGHT)
    for _ in range(s.steps):
        wipe_at(kind, sim, rng)
        sim.step()
        yield sim
    sim.step(integrate=False)
    yield sim


def execute(run: Run, keep: bool = False) -> dict[str, Any]:
    """One run, on a worker: its row. A run that raises is a row with its error, never a lost study. keep: the
    row also carries the run's metrics series (SERIES, records.metrics_columns) under '_series'."""
    from uav_agent.core import ablation

    from .. import provenance
    from .cases import figures, flight_figures, liveness_figures
    t0 = time.perf_counter()
    row: dict[str, Any] = {'key': run.key, 'layout': run.layout, 'seed': run.seed, 'kind': run.kind,
                           'variant': run.variant, 'maps': None, 'duration': None, **dict.fromkeys(FIGURES), 'error': None}
    try:
        s = run.scenario()
        row.update(maps=s.maps, duration=s.duration)
        with ablation.switched_off(run.off):
            for sim in flight(run, s):
                pass
        result = sim.result()
        if keep:
            from world_sim.core.records import metrics_columns
            row['_series'] = dict(zip(metrics_columns(s), result.metrics.T.tolist()))
        row.update(figures(result.metrics, s.dt, EVENT_S.get(run.kind.partition(':')[0])))
        row.update(flight_figures(s, result.metrics, result.trajectory, result.users.centroids, row['converged']))
        row.update(liveness_figures(s, sim.world, result.metrics))
    except Exception as exc:  # noqa: BLE001 -- the row carries it
        row['error'] = f'{type(exc).__name__}: {exc} | {traceback.format_exc(limit=-1).strip().splitlines()[-2].strip()}'
    row.update(code=provenance.code(), wall_s=time.perf_counter() - t0, host=socket.gethostname())
    return row


def _table(rows: list[dict[str, Any]]):  # -> pyarrow.Table
    import pyarrow as pa
    return pa.Table.from_pylist([{c: r.get(c) for c in COLUMNS} for r in rows], schema=schema())


def schema():  # -> pyarrow.Schema
    import pyarrow as pa
    types = {'key': pa.string(), 'layout': pa.int64(), 'seed': pa.int64(), 'kind': pa.string(),
             'variant': pa.string(), 'maps': pa.int64(), 'error': pa.string(), 'code': pa.string(),
             'host': pa.string()}
    return pa.schema([(c, types.get(c, pa.float64())) for c in COLUMNS])


SPEC_COPY = 'spec.yaml'  # the spec a study folder holds the runs of, as it was given


def claim(out: Path, spec_path: Path, keys: set[str], code: str) -> None:
    """Make `out` the folder of this spec's study, flown by this code (provenance.code), or say in one line
    (StudyError) why it is not: it holds the runs of another spec (by its copy of the spec, or, in a folder from
    before the copy, by a row no run of this spec has), runs that other code flew (resumed, the table would mix
    two versions' figures under one key), or it is not a study folder at all (a run folder, say). Then the folder
    keeps a copy of the spec."""
    from world_sim.core.scenario import read_yaml
    copy, held = out / SPEC_COPY, finished(out)
    if copy.exists():
        if read_yaml(copy, 'spec') != read_yaml(spec_path, 'spec'):
            raise StudyError(f'{out} holds the study of another spec (its copy: {copy}): give another --out, or '
                             'that spec')
    elif out.exists() and any(out.iterdir()):
        if not ((out / RESULTS).exists() or (out / PARTS).exists()):
            raise StudyError(f'{out} is not a study folder (no {RESULTS}): give a new or empty --out')
        alien = sorted({r['key'] for r in held} - keys)
        if alien:
            raise StudyError(f'{out} holds {len(alien)} runs of another spec: give another --out, or that spec')
    stale = other_code(held, code)
    if stale:
        raise StudyError(stale + ': give another --out, or fly it with that code')
    out.mkdir(parents=True, exist_ok=True)
    if not copy.exists():
        copy.write_text(spec_path.read_text())


def finished(out: Path) -> list[dict[str, Any]]:
    """The rows a study folder holds: results.parquet and the parts not yet gathered into it (a part is newer:
    it replaces the row of a run that raised and was computed again)."""
    import pyarrow.parquet as pq
    rows: dict[str, dict[str, Any]] = {}
    if (out / RESULTS).exists():
        rows.update((r['key'], r) for r in pq.read_table(out / RESULTS).to_pylist())
    for part in sorted((out / PARTS).glob('*.parquet')) if (out / PARTS).exists() else []:
        rows.update((r['key'], r) for r in pq.read_table(part).to_pylist())
    return list(rows.values())


def other_code(rows: list[dict[str, Any]], code: str) -> Optional[str]:
    """One line on the rows that code other than `code` flew (a row from before runs recorded it counts), or None."""
    other = [r for r in rows if r.get('code') != code]
    if not other:
        return None
    first = other[0]
    return (f'{len(other)} of {len(rows)} runs were flown by other code than this ({code}): the first, layout '
            f'{first["layout"]} seed {first["seed"]}, by {first.get("code") or "code that did not record itself"}')


def raised(rows: list[dict[str, Any]]) -> Optional[str]:
    """One line on the runs that raised (how many, and the first one's place and error), or None."""
    bad = [r for r in rows if r['error'] is not None]
    if not bad:
        return None
    r = bad[0]
    return (f'{len(bad)} of {len(rows)} runs raised (the same command computes them again); the first, layout '
            f'{r["layout"]} seed {r["seed"]} {r["kind"]} {r["variant"]}: {r["error"]}')


def gather(out: Path, order: list[str]) -> Path:
    """results.parquet from everything finished, rows in the spec's grid order; the parts then go."""
    import pyarrow.parquet as pq
    rows = finished(out)
    at = {k: i for i, k in enumerate(order)}
    rows.sort(key=lambda r: at.get(r['key'], len(at)))
    tmp = out / (RESULTS + '.tmp')
    pq.write_table(_table(rows), tmp)
    tmp.replace(out / RESULTS)
    for part in (out / PARTS).glob('*.parquet') if (out / PARTS).exists() else []:
        part.unlink()
    return out / RESULTS


def client_for(scheduler: Optional[str], workers: Optional[int]):  # -> (Client, Optional[LocalCluster])
    """A client of the scheduler named, or of a LocalCluster of one single-threaded worker process a core."""
    from dask.distributed import Client, LocalCluster
    if scheduler:
        return Client(scheduler, timeout='10s'), None
    # The worker processes are started with Ctrl-C ignored: it reaches the whole process group, and this process
    # alone should answer it (the workers end with the cluster, without a traceback each). ':0': a free port for
    # the dashboard, which None does not switch off (dask/distributed#8136), so no warning about 8787 in use.
    # The workers' logs are silenced up to ERROR: what a user needs of them comes back through the futures (a run
    # that raised, a worker lost), and an interrupted study closes the scheduler under a worker's heartbeat,
    # which the worker logs as an error with its traceback ("Failed to communicate with scheduler").
    ignored = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                               dashboard_address=':0', silence_logs=logging.CRITICAL)
    finally:
        signal.signal(signal.SIGINT, ignored)
    return Client(cluster), cluster


@contextmanager
def _quiet_shutdown() -> Iterator[None]:
    """The client and the cluster closed without a word: connections that close under each other while they do
    (CommClosedError, 'Stream is closed') are how a finished study ends, not a fault to print a traceback of."""
    names = ('distributed', 'tornado', 'asyncio')
    levels = {name: logging.getLogger(name).level for name in names}
    for name in names:
        logging.getLogger(name).setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        for name, level in levels.items():
            logging.getLogger(name).setLevel(level)


@contextmanager
def _interruptible() -> Iterator[Callable[[], bool]]:
    """Ctrl-C or SIGTERM stops the study even where Dask's waiting swallows the KeyboardInterrupt (a callback,
    a finalizer): the signal is also remembered, and asked after each run that comes back and at the end."""
    seen: list[int] = []

    def stop(signum: int, frame: Optional[FrameType]) -> None:
        seen.append(signum)
        raise KeyboardInterrupt

    old = {sig: signal.signal(sig, stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield lambda: bool(seen)
        if seen:
            raise KeyboardInterrupt
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def study(runs: list[Run], out: Path, scheduler: Optional[str] = None, workers: Optional[int] = None,
          progress: Callable[[int, int, float], None] = lambda done, total, elapsed: None,
          say: Callable[[str], None] = lambda text: None, keep: bool = False) -> tuple[int, int]:
    """Compute the runs the folder does not hold yet; (runs computed now, runs in all). say: a line for the user
    while nothing else moves (a scheduler with no worker); keep: each run computed leaves its metrics series in
    SERIES/<key>.parquet, written before its row, so a row's series is there if the row is."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from dask.distributed import as_completed
    out.mkdir(parents=True, exist_ok=True)
    (out / PARTS).mkdir(exist_ok=True)
    have = {r['key'] for r in finished(out) if r['error'] is None}  # a run that raised is computed again
    todo = [r for r in runs if r.key not in have]
    done, t0, lost = 0, time.monotonic(), []
    if todo:
        client, cluster = client_for(scheduler, workers)
        try:
            futures = {client.submit(execute, r, keep, key=f'uav-flock-run-{r.key}', pure=False): r for r in todo}
            progress(0, len(todo), 0.0)
            with _interruptible() as stopped:
                if scheduler and not client.scheduler_info().get('workers'):
                    say(f'the scheduler has no worker yet: waiting for one (`dask worker {scheduler}` on a host '
                        'with uav-flock installed)')
                    client.wait_for_workers(1)
                    say('a worker joined')
                for fut in as_completed(futures):
                    if stopped():
                        raise KeyboardInterrupt
                    try:
                        row = fut.result()
                    except Exception as exc:  # noqa: BLE001 -- its workers died under it, or it was cancelled
                        lost.append(f'{futures[fut].key} ({type(exc).__name__})')
                        continue  # not a finished run: the next call computes it again
                    series = row.pop('_series', None)
                    if series is not None:
                        (out / SERIES).mkdir(exist_ok=True)
                        pq.write_table(pa.table(series), out / SERIES / f'{row["key"]}.parquet')
                        _keep_scenario(futures[fut], out / SERIES / f'{row["key"]}.yaml')
                    pq.write_table(_table([row]), out / PARTS / f'{row["key"]}.parquet')
                    done += 1
                    progress(done, len(todo), time.monotonic() - t0)
        finally:
            with _quiet_shutdown():
                client.close()
                if cluster is not None:
                    cluster.close()
            gather(out, [r.key for r in runs])
    else:
        gather(out, [r.key for r in runs])
    if lost:
        raise StudyError(f'{len(lost)} runs came back from no worker (the same command computes them): {", ".join(lost[:3])}')
    return done, len(runs)


def _keep_scenario(run: Run, path: Path) -> None:
    """The run's scenario as flown beside its series: `sim --scenario` of it flies the run again, but for the rules
    its variant switches off (named in the file) and a wipe-out's loss, which the study draws in flight."""
    import yaml
    off = f'# flown with these rules off (core/ablation.py): {", ".join(run.off)}\n' if run.off else ''
    path.write_text(f'# study run {run.key}: layout {run.layout}, seed {run.seed}, {run.kind}, variant {run.variant}\n'
                    + off + yaml.safe_dump(run.doc, sort_keys=False))


class StudyError(RuntimeError):
    """Runs the workers never finished: the study is incomplete, its finished rows kept."""
