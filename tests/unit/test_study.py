"""`uav-flock study` (uav_flock_tools/study/): a grid of runs as Dask tasks into results.parquet, the same on a
local cluster and on a scheduler's worker processes; a killed worker, a Ctrl-C and a bad spec lose nothing."""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml

pytestmark = pytest.mark.slow  # studies on Dask clusters of worker processes

SMOKE = Path(__file__).resolve().parents[2] / 'studies' / 'smoke.yaml'
WHERE = ('wall_s', 'host')  # how long and on which host a run took: not what it found


def study(*args: str, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'study', *args],
                          capture_output=True, text=True, timeout=timeout)


def rows(folder: Path) -> list[dict[str, Any]]:
    return [{k: v for k, v in r.items() if k not in WHERE} for r in pq.read_table(folder / 'results.parquet').to_pylist()]


def parts(folder: Path) -> int:
    return len(list((folder / 'parts').glob('*.parquet'))) if (folder / 'parts').exists() else 0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def wait_for(check, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not check():
        assert time.monotonic() < end, f'timed out waiting for {what}'
        time.sleep(0.2)


@pytest.fixture(scope='module')
def local(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The smoke study on the default local cluster (two workers here)."""
    out = tmp_path_factory.mktemp('local')
    proc = study(str(SMOKE), '--out', str(out), '--workers', '2')
    assert proc.returncode == 0, proc.stderr
    assert '12 runs (12 computed now)' in proc.stdout
    return out


@pytest.fixture(scope='module')
def brief(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The smoke study's grid at 10 s a run, and its rows on the local cluster: where a study goes and what it
    survives (a scheduler, a killed worker, a Ctrl-C) does not need the 60 s that let its runs converge."""
    folder = tmp_path_factory.mktemp('brief')
    spec = folder / 'brief.yaml'
    spec.write_text(yaml.safe_dump({**yaml.safe_load(SMOKE.read_text()), 'duration': 10}))
    proc = study(str(spec), '--out', str(folder / 'local'), '--workers', '2')
    assert proc.returncode == 0, proc.stderr
    assert '12 runs (12 computed now)' in proc.stdout
    return spec, folder / 'local'


def test_the_smoke_study_is_twelve_rows_with_the_figures_of_each_run(local: Path) -> None:
    got = rows(local)
    assert len(got) == 12 and len({r['key'] for r in got}) == 12
    assert [(r['layout'], r['seed'], r['variant']) for r in got[:4]] == \
        [(0, 0, 'demand'), (0, 0, 'algorithm2'), (0, 1, 'demand'), (0, 1, 'algorithm2')], 'the spec\'s grid order'
    assert all(r['error'] is None and r['duration'] == 60.0 for r in got)
    demand = [r for r in got if r['variant'] == 'demand']
    assert all(r['converged'] is not None and 0 < r['connected'] <= 1 for r in demand), demand
    again = study(str(SMOKE), '--out', str(local))
    assert again.returncode == 0 and '(0 computed now)' in again.stdout, 'a second call computes nothing'
    summary = study(str(local), '--summary')
    assert summary.returncode == 0, summary.stderr
    text = (local / 'summary.md').read_text()
    assert '| static | demand | 6 |' in text and '| static | algorithm2 | 6 |' in text
    assert (local / 'connected.png').stat().st_size > 0


def test_every_column_of_the_table_is_documented_and_pandas_reads_it(local: Path) -> None:
    """docs/studies.md, "The table", names every column a study writes; pandas reads it as the docs say."""
    import re
    import pandas
    table = pandas.read_parquet(local / 'results.parquet')
    doc = (Path(__file__).resolve().parents[2] / 'docs' / 'studies.md').read_text()
    section = doc.split('## The table', 1)[1].split('\n## ', 1)[0]
    missing = sorted(set(table.columns) - set(re.findall(r'`(\w+)`', section)))
    assert len(table) == 12 and not missing, f'columns not in docs/studies.md: {missing}'


def test_on_a_scheduler_and_two_worker_processes_a_killed_worker_loses_no_row(brief: tuple[Path, Path],
                                                                             tmp_path: Path) -> None:
    spec, local = brief
    port = free_port()
    address = f'tcp://127.0.0.1:{port}'
    procs = [subprocess.Popen([sys.executable, '-m', 'dask', 'scheduler', '--host', '127.0.0.1', '--port', str(port),
                               '--no-dashboard'], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        wait_for(lambda: socket.socket().connect_ex(('127.0.0.1', port)) == 0, 60, 'the scheduler')
        workers = [subprocess.Popen([sys.executable, '-m', 'dask', 'worker', address, '--nthreads', '1',
                                     '--no-dashboard'], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                   for _ in range(2)]
        procs += workers
        out = tmp_path / 'on-scheduler'
        run = subprocess.Popen([sys.executable, '-m', 'uav_flock_tools.cli', 'study', str(spec), '--out', str(out),
                                '--scheduler', address], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        procs.append(run)
        wait_for(lambda: parts(out) >= 2 or run.poll() is not None, 300, 'the first rows')
        assert run.poll() is None, 'the study ended before a worker could be killed'
        workers[0].kill()  # SIGKILL: its run, if any, goes to the other worker
        stdout, stderr = run.communicate(timeout=600)
        assert run.returncode == 0, stderr
        assert rows(out) == rows(local), 'row by row, the same as on the local cluster'
    finally:
        for p in procs:
            p.kill()
            p.wait()


def test_an_interrupted_study_keeps_its_rows_and_the_next_call_computes_only_the_rest(brief: tuple[Path, Path],
                                                                                      tmp_path: Path) -> None:
    spec, local = brief
    out = tmp_path / 'interrupted'
    run = subprocess.Popen([sys.executable, '-m', 'uav_flock_tools.cli', 'study', str(spec), '--out', str(out),
                            '--workers', '1'], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           start_new_session=True)
    wait_for(lambda: parts(out) >= 3 or run.poll() is not None, 300, 'three rows')
    assert run.poll() is None, 'the study ended before it could be interrupted'
    os.killpg(run.pid, signal.SIGINT)  # Ctrl-C in a terminal: the study and its local workers alike
    _, stderr = run.communicate(timeout=120)
    assert run.returncode == 130, stderr
    kept = rows(out)
    assert 3 <= len(kept) < 12 and parts(out) == 0, 'every finished row gathered into results.parquet'
    assert 'Traceback' not in stderr and 'CancelledError' not in stderr, f'the workers spoke:\n{stderr}'
    assert f'{len(kept)} of 12 runs kept' in stderr.splitlines()[-1], stderr
    assert all(r['error'] is None for r in kept), 'no run counted finished that the interrupt cut short'
    rest = study(str(spec), '--out', str(out), '--workers', '2')
    assert rest.returncode == 0, rest.stderr
    assert f'12 runs ({12 - len(kept)} computed now)' in rest.stdout
    assert rows(out) == rows(local)


@pytest.mark.parametrize('spec, says', [
    ({'layouts': {'count': 1}, 'colour': 'red'}, 'colour: unknown key'),
    ({'layouts': {'count': 1}, 'seeds': []}, 'seeds: an empty list'),
    ({'layouts': {'count': 1}, 'seeds': -2}, 'seeds: expected a positive integer, got -2'),
    ({'layouts': {'count': 'three'}}, "layouts.count: expected a positive integer, got 'three'"),
    ({'layouts': {'count': 2.5}}, 'layouts.count: expected a positive integer, got 2.5'),
    ({'layouts': {'count': 1, 'seed': 'x'}}, "layouts.seed: expected a non-negative integer, got 'x'"),
    ({'layouts': {'count': 1, 'clusters': '4-3'}}, "layouts.clusters: expected [LO, HI]"),
    ({'layouts': {'count': 1, 'cluster': 3}}, 'layouts.cluster: unknown key; did you mean clusters?'),
    ({'layouts': {'count': 1, 'vehicle': 'jet'}}, "layouts.vehicle: must be one of ideal, multirotor, x500, got 'jet'"),
    ({'seeds': 1}, 'layouts: missing: give layouts'),
    ({'layouts': {'count': 1}, 'variants': {'a': {'flock': {'cl': 0.4}}}}, 'flock.cl: unknown key; did you mean c1?'),
    ({'layouts': {'count': 1}, 'kinds': ['drift:fast']}, 'must be a number'),
    ({'layouts': {'count': 1}, 'kinds': ['hover']}, "'hover': expected one of"),
    ({'layouts': {'count': 1}, 'variants': {'odd': {'flock.nope': 1}}}, 'variants: odd: '),
    ({'scenario': 'paper', 'layouts': {'count': 1}}, 'either layouts'),
    ({'layouts': {'count': 1}, 'variants': {'ab': {'without': ['hold', 'nope']}}}, 'variants: ab: without: nope: no such rule'),
    ({'layouts': {'count': 1}, 'variants': {True: {'vehicle.model': 'multirotor'}}}, 'variants: True is read as bool, not a name: quote it'),
])
def test_a_bad_spec_is_one_line_and_exit_2(tmp_path: Path, spec: dict, says: str) -> None:
    (tmp_path / 'bad.yaml').write_text(yaml.safe_dump(spec))
    proc = study(str(tmp_path / 'bad.yaml'), '--out', str(tmp_path / 'out'))
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1 and says in proc.stderr, proc.stderr
    assert not (tmp_path / 'out').exists()


@pytest.mark.parametrize('text, says', [
    ('layouts: {count: 1\nseeds: 2\n', 'not valid YAML at line 2'),
    ('layouts: {count: 1}\nseeds: 1\nseeds: 2\n', "not valid YAML at line 3, column 1 ('seeds' is given twice"),
])
def test_a_spec_that_is_no_yaml_names_its_line_and_its_path_once(tmp_path: Path, text: str, says: str) -> None:
    (tmp_path / 'bad.yaml').write_text(text)
    proc = study(str(tmp_path / 'bad.yaml'), '--out', str(tmp_path / 'out'))
    assert proc.returncode == 2 and says in proc.stderr and proc.stderr.count('bad.yaml') == 1, proc.stderr


def test_a_spec_with_clusters_as_the_layouts_command_writes_them_and_a_nested_variant_flies(tmp_path: Path) -> None:
    from uav_flock_tools.study.spec import load, runs
    (tmp_path / 's.yaml').write_text(yaml.safe_dump({'layouts': {'count': 1, 'clusters': '3-4'}, 'duration': 1,
                                                      'variants': {'a': {'flock': {'c1': 0.4}}}}))
    grid = runs(load(tmp_path / 's.yaml'))
    assert len(grid) == 1 and grid[0].doc['flock']['c1'] == 0.4 and 3 <= len(grid[0].doc['users']['clusters']) <= 4


def test_a_scheduler_that_is_not_there_is_one_line_and_exit_2(tmp_path: Path) -> None:
    proc = study(str(SMOKE), '--out', str(tmp_path / 'out'), '--scheduler', f'tcp://127.0.0.1:{free_port()}')
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1 and 'no scheduler there' in proc.stderr, proc.stderr


def test_under_a_channel_connected_is_the_usable_graph_and_disc_the_disc_graph() -> None:
    """The issue's targets under a radio are the usable graph's (docs/links.md): a run whose disc graph holds
    while a link that delivers less than half breaks is connected that share less, its disc figure whole."""
    from uav_flock_tools.study.cases import figures
    from world_sim.core.hearing import LINK_COLUMNS
    from world_sim.core.records import METRICS_COLUMNS
    m = np.zeros((200, len(METRICS_COLUMNS) + len(LINK_COLUMNS)))
    m[:, 1], m[:, 2], m[:, 3], m[:, 4], m[:, 5] = np.arange(200) * 0.1, 0.97, 0.4, 10, 1
    m[:, len(METRICS_COLUMNS):len(METRICS_COLUMNS) + 2] = 0.2, 1  # the usable graph's lambda2 and components
    m[60:80, len(METRICS_COLUMNS):len(METRICS_COLUMNS) + 2] = 0.0, 2  # 2 s of it split, the disc graph whole
    f = figures(m, 0.1, None)
    assert f['connected'] == pytest.approx(0.9) and f['disc'] == 1.0 and f['outage'] == pytest.approx(2.0)
    assert f['ends_ok'] == 1.0 and f['converged'] == 0.0 and f['splits'] == 1.0
    assert figures(m[:, :len(METRICS_COLUMNS)], 0.1, None)['connected'] == 1.0, 'the paper\'s channel: the disc graph'


def test_a_formation_counts_as_formed_once_every_map_is_slower_than_the_bound_and_connected_counts_on_from_there() -> None:
    """A multirotor's formation first converges while MAPs still fly to their roles: `formed` is the first step
    covered and connected with every MAP slower than FORMED_SPEED, and `connected_formed` the share connected from
    it on, so a split while one MAP was still on its way counts in `connected` and not there; a step the trajectory
    did not record is not one at rest, and a formation never at rest has neither figure."""
    from uav_flock_tools.study.cases import FORMED_SPEED, figures, formation
    from world_sim.core.records import METRICS_COLUMNS, TRAJECTORY_COLUMNS
    m = np.zeros((300, len(METRICS_COLUMNS)))
    m[:, 0], m[:, 1], m[:, 2], m[:, 3], m[:, 4], m[:, 5] = np.arange(300), np.arange(300) * 0.1, 0.97, 0.4, 2, 1
    m[:50, 5] = 2  # converges at 5 s
    m[60:70, 5] = 2  # split 1 s while MAP 1 is on its way
    m[250:260, 5] = 2  # and 1 s after the formation is at rest
    steps = np.repeat(np.arange(300), 2)
    traj = np.zeros((600, len(TRAJECTORY_COLUMNS)))
    col = TRAJECTORY_COLUMNS.index
    traj[:, col('step')], traj[:, col('id')] = steps, np.tile([0, 1], 300)
    traj[:, col('vx')] = np.where((traj[:, col('id')] == 1) & (steps < 100), FORMED_SPEED + 5.0, 0.5)
    f, g = figures(m, 0.1, None), formation(m, traj)
    assert f['converged'] == pytest.approx(5.0) and f['connected'] == pytest.approx(230 / 250)
    assert g['formed'] == pytest.approx(10.0) and g['connected_formed'] == pytest.approx(190 / 200)
    unrecorded = traj[traj[:, col('step')] != 100]
    assert formation(m, unrecorded)['formed'] == pytest.approx(10.1)
    traj[:, col('vy')] = FORMED_SPEED
    assert formation(m, traj) == {}


def test_splits_count_each_fall_apart_after_convergence_and_the_summary_the_runs_never_split() -> None:
    """A network that falls apart twice after convergence splits twice, however long each lasts; one split
    before convergence is no split; the summary counts the converged runs that never split."""
    from uav_flock_tools.study.cases import figures
    from uav_flock_tools.study.summary import cells
    from world_sim.core.records import METRICS_COLUMNS
    m = np.zeros((300, len(METRICS_COLUMNS)))
    m[:, 1], m[:, 2], m[:, 3], m[:, 4], m[:, 5] = np.arange(300) * 0.1, 0.97, 0.4, 10, 1
    m[:50, 3], m[:50, 5] = 0.0, 2  # split before it first converges (t = 5 s)
    m[100:101, 3], m[100:101, 5] = 0.0, 2  # one step apart
    m[200:260, 3], m[200:260, 5] = 0.0, 3  # 6 s apart, in three pieces
    f = figures(m, 0.1, None)
    assert f['converged'] == pytest.approx(5.0) and f['splits'] == 2.0 and f['outage'] == pytest.approx(6.0)
    whole = figures(np.delete(m, np.r_[100, 200:260], axis=0), 0.1, None)
    assert whole['splits'] == 0.0
    grid = {'kind': 'static', 'variant': 'a', 'seed': 0, 'error': None}
    rows = [{**grid, 'layout': 0, **f}, {**grid, 'layout': 1, **whole}, {**grid, 'layout': 2, **figures(m[:40], 0.1, None)}]
    assert rows[2]['converged'] is None
    assert cells(rows)[0]['unsplit'] == 1 and cells(rows)[0]['converged'] == 2


def test_a_variant_flies_with_the_rules_it_switches_off_and_only_that_run(tmp_path: Path) -> None:
    """`without:` in a variant is an ablation inside a study: the run equals the batch simulator's with those rules
    off, its key differs from the run with every rule on, and no rule stays off after it."""
    from uav_agent.core import ablation
    from uav_flock_tools.batch import BatchSimulator
    from uav_flock_tools.study import spec as specs
    from uav_flock_tools.study.cases import FIGURES, figures, flight_figures, liveness_figures
    from uav_flock_tools.study.engine import execute
    (tmp_path / 's.yaml').write_text(  # as a user types it
        'layouts: {count: 1, clusters: [3, 3]}\nkinds: [static]\nduration: 8\nvariants:\n'
        '  all: {links.loss: 0.3, links.burst: 5}\n'
        '  no_hearsay: {links.loss: 0.3, links.burst: 5, without: [hearsay]}\n')
    on, off = specs.runs(specs.load(tmp_path / 's.yaml'))
    assert off.off == ('hearsay',) and on.off == () and on.key != off.key and on.doc == off.doc
    row = execute(off)
    assert row['error'] is None and ablation.on('hearsay')
    s = off.scenario()
    with ablation.switched_off(['hearsay']):
        sim = BatchSimulator(s)
        flown = sim.run()
    alone = flown.metrics
    expected = figures(alone, s.dt, None)  # a random layout flies the multirotor: its flight figures too
    expected.update(flight_figures(s, alone, flown.trajectory, flown.users.centroids, expected['converged']))
    expected.update(liveness_figures(s, sim.world, alone))
    assert not s.vehicle.ideal and {k: row[k] for k in FIGURES} == expected
    assert not np.array_equal(alone, BatchSimulator(on.scenario()).run().metrics), 'hearsay acts on this run'


def test_a_run_that_raised_is_named_in_one_line_and_computed_again_by_the_next_call(tmp_path: Path) -> None:
    """A run whose code raises is a row with its error, not a lost study; the study says which and how, and the
    same call again computes that run (the code fixed) instead of keeping the error as a finished row."""
    import dataclasses

    from uav_flock_tools.study import engine
    from uav_flock_tools.study import spec as specs
    (tmp_path / 's.yaml').write_text('layouts: {count: 1, clusters: [3, 3]}\nkinds: [static]\nduration: 3\n')
    good, = specs.runs(specs.load(tmp_path / 's.yaml'))
    broken = dataclasses.replace(good, doc={**good.doc, 'flock': {**good.doc['flock'], 'r': 'far'}})
    out = tmp_path / 'out'
    assert engine.study([broken], out, workers=1) == (1, 1)
    line = engine.raised(engine.finished(out))
    assert line is not None and line.startswith('1 of 1 runs raised') and 'layout 0 seed 0 static base' in line
    assert '\n' not in line
    assert engine.study([good], out, workers=1) == (1, 1), 'the run that raised is computed again'
    row, = engine.finished(out)
    assert row['error'] is None and row['duration'] == 3.0 and engine.raised([row]) is None
    assert engine.study([good], out, workers=1) == (0, 1), 'a finished run is not'


def test_keep_leaves_each_runs_series_that_pandas_reads_and_a_row_flies_again(tmp_path: Path) -> None:
    """`study --keep`: series/<key>.parquet beside results.parquet, a column per metric of metrics.csv and a row a
    step, whose last row is the row's end; engine.execute flies that row again to the same series
    (docs/studies.md)."""
    import pandas as pd

    from uav_flock_tools.study import engine
    from uav_flock_tools.study import spec as specs
    from world_sim.core.records import metrics_columns
    (tmp_path / 's.yaml').write_text('layouts: {count: 1, clusters: [3, 3]}\nkinds: [static]\nduration: 3\n'
                                     'variants:\n  multirotor: {vehicle.model: multirotor}\n')
    run, = specs.runs(specs.load(tmp_path / 's.yaml'))
    out = tmp_path / 'out'
    proc = study(str(tmp_path / 's.yaml'), '--out', str(out), '--workers', '1', '--keep')
    assert proc.returncode == 0, proc.stderr
    series = pd.read_parquet(out / 'series' / f'{run.key}.parquet')
    row, = engine.finished(out)
    assert tuple(series.columns) == metrics_columns(run.scenario()) and len(series) == run.scenario().steps + 1
    assert series['coverage_ratio'].iloc[-1] == row['end_rc']
    assert series['min_distance'].min() == row['least_distance']
    again = engine.execute(run, keep=True)['_series']
    assert again == {c: series[c].tolist() for c in series.columns}
    # ... and the run's scenario beside it, which `sim` flies again to the same metrics
    flown = out / 'series' / f'{run.key}.yaml'
    proc = subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'sim', '--scenario', str(flown), '--out',
                           str(tmp_path / 'again')], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    metrics = pd.read_csv(tmp_path / 'again' / 'metrics.csv')
    assert metrics['coverage_ratio'].tolist() == series['coverage_ratio'].tolist()


def test_a_study_folder_keeps_its_spec_and_refuses_the_runs_of_another(local: Path, tmp_path: Path) -> None:
    """Another spec into the smoke study's folder would mix two studies in one table (two layouts 0 read as one):
    refused in one line, exit 2, nothing written; so is a folder of no study (a sim run's), and a folder from
    before the copy whose rows the spec has not."""
    import shutil
    assert yaml.safe_load((local / 'spec.yaml').read_text()) == yaml.safe_load(SMOKE.read_text())
    other = tmp_path / 'other.yaml'
    other.write_text(yaml.safe_dump({**yaml.safe_load(SMOKE.read_text()), 'duration': 5, 'variants': {'base': {}}}))
    before = rows(local)
    proc = study(str(other), '--out', str(local))
    assert proc.returncode == 2 and proc.stderr.count('\n') == 1 and 'another spec' in proc.stderr, proc.stderr
    assert rows(local) == before and parts(local) == 0
    old = tmp_path / 'old'
    shutil.copytree(local, old)
    (old / 'spec.yaml').unlink()
    proc = study(str(other), '--out', str(old))
    assert proc.returncode == 2 and 'runs of another spec' in proc.stderr, proc.stderr
    assert not (old / 'spec.yaml').exists()
    run = tmp_path / 'run'
    run.mkdir()
    (run / 'metrics.csv').write_text('step,t\n')
    proc = study(str(other), '--out', str(run))
    assert proc.returncode == 2 and 'not a study folder' in proc.stderr, proc.stderr
    assert sorted(p.name for p in run.iterdir()) == ['metrics.csv']


def test_a_study_folder_flown_by_other_code_is_refused_and_names_the_code_of_each_run(tmp_path: Path) -> None:
    """A run's key hashes its scenario, not the code: resumed by changed code, one table would hold two versions'
    figures under one spec. Each row names the digest of the code that flew it (provenance.code), the folder the
    command that flew into it, and a copy of the agent's code changed by one line on PYTHONPATH is refused in one
    line, exit 2, the rows untouched."""
    import json
    import shutil

    import uav_agent
    from uav_flock_tools import provenance
    (tmp_path / 's.yaml').write_text('layouts: {count: 1, clusters: [3, 3]}\nkinds: [static]\nduration: 3\n')
    out = tmp_path / 'out'
    proc = study(str(tmp_path / 's.yaml'), '--out', str(out), '--workers', '1')
    assert proc.returncode == 0, proc.stderr
    row, = rows(out)
    assert row['code'] == provenance.code() and row['error'] is None, row
    said = json.loads((out / 'provenance.json').read_text())
    assert said['code'] == provenance.code() and said['command'][:2] == ['uav-flock', 'study'], said
    copy = tmp_path / 'copy' / 'uav_agent'
    shutil.copytree(Path(uav_agent.__file__).parent, copy, ignore=shutil.ignore_patterns('__pycache__'))
    with (copy / 'core' / 'safety.py').open('a') as f:
        f.write('\nMARGIN_OF_ANOTHER_VERSION = 2.0\n')
    env = {**os.environ, 'PYTHONPATH': f'{copy.parent}{os.pathsep}{os.environ.get("PYTHONPATH", "")}'}
    other = subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'study', str(tmp_path / 's.yaml'), '--out',
                            str(out), '--workers', '1'], capture_output=True, text=True, timeout=300, env=env)
    assert other.returncode == 2 and other.stderr.count('\n') == 1, other.stderr
    assert 'flown by other code' in other.stderr and row['code'] in other.stderr, other.stderr
    assert rows(out) == [row] and parts(out) == 0
    again = study(str(tmp_path / 's.yaml'), '--out', str(out), '--workers', '1')
    assert again.returncode == 0 and '1 runs (0 computed now)' in again.stdout, again.stdout + again.stderr
