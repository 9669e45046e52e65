"""`uav-flock trace` (uav_flock_tools/trace.py): one study run flown again, to the bit, saying when the network fell
into pieces, who was cut off, and for a MAP asked about its nominal, its command and what the filter did."""
from __future__ import annotations

import io
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from helpers.runs import cli
from uav_agent.core import ablation
from uav_flock_tools.study import engine
from uav_flock_tools.study.spec import load, runs
from uav_flock_tools.trace import ALREADY, Outage, Traced, Window, began, pick, summary, trace
from world_sim.core.physics import component_labels

pytestmark = pytest.mark.slow  # each test flies runs of 25 s

SPEC = {'layouts': {'count': 1, 'clusters': [3, 3], 'seed': 0}, 'seeds': 1, 'kinds': ['static'], 'duration': 25,
        'variants': {'rules': {'vehicle.model': 'multirotor'},
                     'filter': {'vehicle.model': 'multirotor', 'policies.safety': 'filter'}}}
IDEAL = {**SPEC, 'layouts': {**SPEC['layouts'], 'vehicle': 'ideal'}, 'variants': {'ideal': {}}}
PIECES = re.compile(r'^t=\s*([\d.]+)\s+pieces (\d+) -> (\d+):')
MAP_LINE = re.compile(r'^t=\s*([\d.]+)\s+MAP (\d+) .*nominal ([\d.]+) m/s² .*, command (the same|[\d.]+ m/s²)')


@pytest.fixture(scope='module')
def spec(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp('trace')
    (folder / 'ideal.yaml').write_text(yaml.safe_dump(IDEAL))
    (folder / 'brief.yaml').write_text(yaml.safe_dump(SPEC))
    return folder / 'brief.yaml'


def traced(spec: Path, variant: str, window: Window) -> tuple[str, Traced]:
    run = pick(runs(load(spec if variant != 'ideal' else spec.with_name('ideal.yaml'))), '0/0/static', variant)
    out = io.StringIO()
    with ablation.switched_off(run.off):
        seen = trace(engine.flight(run, run.scenario(), watch=True), window, out)
    return out.getvalue(), seen


def test_the_pieces_it_reports_are_those_of_the_run_as_the_study_flies_it(spec: Path) -> None:
    """The trace watches the run without changing it: the pieces the MAP graph within r falls into, counted from
    the study's own flight (no watch) step by step, change exactly where the trace says they do. Under the filter,
    whose links the trace reads too; the rules' run folder is the test below."""
    variant = 'filter'
    run = pick(runs(load(spec)), '0/0/static', variant)
    s = run.scenario()
    counts: dict[float, int] = {}
    with ablation.switched_off(run.off):
        for sim in engine.flight(run, s):  # each step's world once it has moved on: the MAPs where step k finds them
            w = sim.world
            ids = w.ids[w.alive]
            q = w.q[ids][:, :2]
            near = np.argwhere(np.linalg.norm(q[:, None] - q[None], axis=-1) <= s.flock.r)
            counts[round(w.k * s.dt, 1)] = int(component_labels(near, len(ids)).max()) + 1
    counts = sorted(counts.items())
    expected = [(t, b) for (_, a), (t, b) in zip(counts, counts[1:]) if a != b]
    text, seen = traced(spec, variant, Window())
    said = [(float(m[1]), int(m[3])) for m in map(PIECES.match, text.splitlines()) if m]
    assert said == expected[:len(said)] and len(said) >= len(expected) - 1, (said[:5], expected[:5])
    assert len(said) >= 2, 'a deployment from one release square falls into pieces and joins: the case tests nothing'
    assert seen.splits == sum(b > a for (_, a), (_, b) in zip([(0, counts[0][1])] + said, said))
    # each outage: from one network falling apart (or the start, in pieces) to one network again
    apart, since = [], None
    for t, count in [(counts[0][0], counts[0][1])] + expected:
        if since is None and count > 1:
            since = t
        elif since is not None and count == 1:
            apart.append((since, t))
            since = None
    closed = [(o.start, o.end) for o in seen.outages[:len(apart)]]
    assert closed == apart[:len(closed)] and len(seen.outages) >= len(apart), (seen.outages[:3], apart[:3])
    first = seen.outages[0]
    assert first.began.endswith('of a MAP on its first flight'), 'the release square falls apart as the MAPs fly out'
    # a window that opens inside an outage says so, and closes it where the whole run's trace does
    middle = round((first.start + first.end) / 2, 1)
    _, late = traced(spec, variant, Window((), middle, first.end + 1.0))
    assert late.outages[0] == Outage(middle, first.end, ALREADY), late.outages


def test_what_began_an_outage_and_the_summary_of_a_window() -> None:
    """The summary says how long the network was apart and what began each time: a link the filter kept that gave
    way first, else the most mobile MAP among the ends of the links that broke."""
    assert began(True, ['S3 in transit']) == 'a link the network needs gave way'
    assert began(False, ['R(1, 2) settled', 'S3 in transit']) == 'a link kept by neither end, of a MAP in transit'
    assert began(False, ['S0 settled', 'S2 first flight']).endswith('a MAP on its first flight')
    assert began(False, ['S0 settled', 'R(0, 2) settled']).endswith('settled MAPs')
    assert began(False, ['S0', 'S1']) == 'a link kept by neither end', 'Algorithm 2 says nothing of how far a MAP is'
    window = Window((), 40.0, 100.0)
    lines = summary(Traced(3, [Outage(46.3, 48.5, 'a link kept by neither end, of a MAP in transit'),
                               Outage(53.3, 67.6, 'a link the network needs gave way')]), window)
    assert lines[0] == 'trace: 3 splits from 40 s to 100 s; apart 16.5 s of the 60 s (27.5 %), in 2 outages:'
    assert lines[1:] == ['    46.3-48.5 s (2.2 s), begun by a link kept by neither end, of a MAP in transit',
                         '    53.3-67.6 s (14.3 s), begun by a link the network needs gave way']
    assert summary(Traced(0, []), window) == ['trace: 0 splits from 40 s to 100 s; one network throughout']


def test_on_the_papers_vehicle_the_command_is_the_nominal_and_on_the_multirotor_not_always(spec: Path) -> None:
    """The paper's vehicle flies eq. 9 as it is; the multirotor's filter or rules change the nominal where it would
    leave the envelope or close on a neighbour, and the trace says by how much."""
    window = Window((0, 5), 0.0, 20.0, 2.0)
    for variant in ('ideal', 'filter'):
        text, _ = traced(spec, variant, window)
        lines = [m for m in map(MAP_LINE.match, text.splitlines()) if m]
        assert [(float(m[1]), int(m[2])) for m in lines] == [(t, i) for t in np.arange(0, 20.1, 2.0) for i in (0, 5)]
        same = [m[4] == 'the same' for m in lines]
        if variant == 'ideal':
            assert all(same)
        else:
            assert not all(same), 'no command of the multirotor differed from its nominal'
            assert all(float(m[4].split()[0]) <= 4.0 + 1e-6 for m, s in zip(lines, same) if not s), 'within a_max'


def test_a_run_named_wrong_is_one_line_and_exit_2(spec: Path) -> None:
    for args, says in ((['9/0/static'], 'no run 9/0/static in the spec'),
                       (['0/0/drift:2'], 'no run 0/0/drift:2 in the spec'),
                       (['0/0/static'], 'flown by 2 variants: say which with --variant'),
                       (['0/0/static', '--variant', 'rules', '--map', '500'], '--map: the run flies MAPs 0-'),
                       (['nonsense'], 'neither a run key of the spec nor LAYOUT/SEED/KIND'),
                       ([], 'a study names many runs: say which'),
                       (['0/0/static', '--variant', 'rules', '--from', '5', '--to', '2'], '--to comes before --from')):
        done = cli('trace', str(spec), *args)
        assert done.returncode == 2 and done.stderr.count('\n') == 1 and 'Traceback' not in done.stderr, done.stderr
        assert says in done.stderr, done.stderr
    done = cli('trace', str(spec.parent))
    assert done.returncode == 2 and 'neither spec.yaml (a study) nor scenario.yaml' in done.stderr, done.stderr


def test_a_run_folder_of_sim_is_flown_again_to_the_pieces_its_records_hold(tmp_path: Path) -> None:
    """`trace RUN_FOLDER` flies the folder's scenario.yaml again: the pieces it reports change exactly where the
    components column of the folder's metrics.csv does."""
    folder = tmp_path / 'drift'
    done = cli('sim', '--scenario', 'drift', '--duration', '20', '--seed', '1', '--out', str(folder))
    assert done.returncode == 0, done.stderr
    metrics = np.genfromtxt(folder / 'metrics.csv', delimiter=',', names=True)
    steps = [(round(float(t), 1), int(c)) for t, c in zip(metrics['t'], metrics['components'])]
    expected = [(t, b) for (_, a), (t, b) in zip(steps, steps[1:]) if a != b]
    done = cli('trace', str(folder), '--map', '3', '--to', '20')
    assert done.returncode == 0, done.stderr
    said = [(float(m[1]), int(m[3])) for m in map(PIECES.match, done.stdout.splitlines()) if m]
    assert len(expected) >= 2, 'the run never fell into pieces: the case tests nothing'
    assert said == expected
    assert len([m for m in map(MAP_LINE.match, done.stdout.splitlines()) if m]) == 21  # 0, 1, ..., 20 s
    apart = sum(t1 - t0 for (t0, c), (t1, _) in zip(steps, steps[1:]) if c > 1)
    total = re.search(r'; apart ([\d.]+) s of the 20 s', done.stdout)
    assert total and abs(float(total[1]) - apart) < 0.15, (done.stdout.splitlines()[-3:], apart)


def test_a_reader_that_leaves_ends_the_trace_quietly(spec: Path) -> None:
    """`trace ... | head -2`: its stdout is what it makes (cli.PRINTERS), so it ends with its reader, exit 0 and
    no traceback, as `echo` does."""
    command = shlex.join([sys.executable, '-m', 'uav_flock_tools.cli', 'trace', str(spec), '0/0/static', '--variant',
                          'rules', '--map', '0'])
    done = subprocess.run(['bash', '-c', f'{command} | head -2; exit ${{PIPESTATUS[0]}}'], capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0 and 'Traceback' not in done.stderr, done.stderr
    assert len(done.stdout.splitlines()) == 2 and done.stdout.startswith('trace: layout 0, seed 0, static')


ARRIVAL = {'layouts': {'count': 1, 'clusters': [3, 3], 'seed': 0, 'vehicle': 'ideal'}, 'seeds': 1, 'kinds': ['arrival'],
           'duration': 50, 'variants': {'ideal': {}}}
PER_RUN = re.compile(r'^  (\d+)/(\d+)/(\S+) (\S+): apart ([\d.]+) s of the ([\d.]+) s after first convergence, (\d+) outage')


def test_outages_over_a_study_add_up_to_its_connected_column(tmp_path: Path) -> None:
    """`trace STUDY --outages` flies again each run that split after first convergence: the time it says each was
    apart is the time its `connected` column says it was not, and the census adds them up. Arrivals on the paper's
    vehicle: the arriving cluster's MAPs leave the formation, so the runs split after converging."""
    (tmp_path / 'arrival.yaml').write_text(yaml.safe_dump(ARRIVAL))
    out = tmp_path / 'study'
    done = cli('study', str(tmp_path / 'arrival.yaml'), '--out', str(out))
    assert done.returncode == 0, done.stderr
    rows = {(r['layout'], r['seed']): r for r in engine.finished(out)}
    split = [r for r in rows.values() if r['converged'] is not None and r['connected'] < 1.0]
    assert split, 'no arrival split after converging: the case tests nothing'
    done = cli('trace', str(out), '--outages')
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith(f'trace: {len(rows)} of {len(rows)} runs converged, {len(split)} of them split after '
                                'it'), lines[0]
    seen = [m for m in map(PER_RUN.match, lines) if m]
    assert len(seen) == len(split)
    dt = 0.1
    for m in seen:
        r = rows[(int(m[1]), int(m[2]))]
        window = float(m[6])
        assert abs(window - (r['duration'] - r['converged'])) < 0.05
        # `connected` is the share of the steps from first convergence to the end, both counted
        assert abs(float(m[5]) - (1.0 - r['connected']) * (window + dt)) <= 2 * dt + 1e-9, (m[0], r['connected'])
    total = sum(float(m[5]) for m in seen)
    head = next(line for line in lines if line.startswith('outages after first convergence'))
    said = re.search(r'(\d+) runs?, ([\d.]+) s after it in all; apart ([\d.]+) s', head)
    assert said and int(said[1]) == len(rows) and abs(float(said[3]) - total) <= 0.1 * len(seen), head
    assert abs(float(said[2]) - sum(r['duration'] - r['converged'] for r in rows.values())) < 0.05 * len(rows)
    table = [line for line in lines[lines.index(head) + 2:] if line.strip()]
    assert sum(int(line.split()[-1]) for line in table) == sum(int(m[7]) for m in seen)
    # the paper's vehicle never comes to rest below 3 m/s in every MAP: no run formed, so every outage is before it
    assert all(' not yet ' in line for line in table), table
    wrong = cli('trace', str(out), '--outages', '--kind', 'static')
    assert wrong.returncode == 2 and "no run of kind 'static'" in wrong.stderr and 'Traceback' not in wrong.stderr
    wrong = cli('trace', str(tmp_path / 'arrival.yaml'), '--outages')
    assert wrong.returncode == 2 and 'reads a study folder' in wrong.stderr, wrong.stderr
