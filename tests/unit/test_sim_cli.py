"""The command line: the files `sim` writes, one folder per run when there are several; user mistakes and Ctrl-C."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from world_sim.core.records import METRICS_COLUMNS, TRAJECTORY_COLUMNS, read_csv, read_trajectory

pytestmark = pytest.mark.slow  # every test runs the command line


GOLDEN_BAG = Path(__file__).resolve().parents[1] / 'golden' / 'bag'


def sim(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'sim', *args],
                          capture_output=True, text=True, timeout=300)


def test_single_run_writes_csvs_and_plots(tmp_path: Path) -> None:
    proc = sim('--maps', '12', '--seed', '4', '--duration', '3', '--out', str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / 'metrics.csv').read_text().splitlines()[0] == ','.join(METRICS_COLUMNS)
    assert (tmp_path / 'trajectory.csv').read_text().splitlines()[0] == ','.join(TRAJECTORY_COLUMNS)
    m, t = read_csv(tmp_path / 'metrics.csv'), read_csv(tmp_path / 'trajectory.csv')
    assert len(m['step']) == 31 and len(t['step']) == 31 * 12
    by_column = read_trajectory(tmp_path)
    for c in TRAJECTORY_COLUMNS:  # the same rows by column; t as computed, where the CSV prints 10 digits
        assert np.array_equal(by_column[c], t[c]) if c != 't' else np.allclose(by_column[c], t[c], rtol=1e-9), c
    assert np.all((m['coverage_ratio'] >= 0) & (m['coverage_ratio'] <= 1))
    assert np.all(m['mode0'] + m['mode1'] + m['mode2'] == m['alive'])
    for png in ('coverage.png', 'fiedler.png', 'modes.png', 'formation.png'):
        assert (tmp_path / png).read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    with Image.open(tmp_path / 'formation.gif') as gif:
        assert gif.n_frames == 4, 'one frame a second of simulated time, t = 0 to 3 s'


def test_the_animation_marks_the_maps_lost_where_they_were(tmp_path: Path) -> None:
    """A run losing half its MAPs at 1 s: the first frame shows no lost MAP (only the legend's marker is red),
    the last shows them in red."""
    proc = sim('--maps', '12', '--seed', '4', '--duration', '3', '--fail-at', '1', '--fail-fraction', '0.5',
               '--out', str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    lost_red = np.array([214, 39, 40])  # matplotlib's tab:red, the lost MAPs' marker

    def red_pixels(frame: int) -> int:
        with Image.open(tmp_path / 'formation.gif') as gif:
            gif.seek(frame)
            rgb = np.asarray(gif.convert('RGB'), dtype=int)
        return int(np.sum(np.abs(rgb - lost_red).sum(axis=-1) < 30))

    legend = red_pixels(0)  # the legend's marker: no MAP is lost yet
    assert red_pixels(3) > legend + 6 * 10, 'six MAPs lost, each a red X of some tens of pixels'


def test_several_runs_get_a_folder_each_and_failures_drop_maps(tmp_path: Path) -> None:
    proc = sim('--maps', '10,20', '--seed', '0', '--duration', '2', '--fail-at', '1', '--fail-fraction', '0.5',
               '--out', str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    for n in (10, 20):
        m = read_csv(tmp_path / f'maps{n}_seed0' / 'metrics.csv')
        assert m['alive'][0] == n and m['alive'][-1] == n // 2
        failures = json.loads((tmp_path / f'maps{n}_seed0' / 'failures.json').read_text())
        [event] = failures['events']
        assert event['step'] == 10 and event['cause'] == 'scheduled' and event['ids'] == failures['failed']
    assert (tmp_path / 'coverage.png').exists() and (tmp_path / 'fiedler.png').exists()
    assert not list(tmp_path.glob('maps*/*.png')) and not list(tmp_path.glob('maps*/*.gif')), \
        "a sweep draws each run's pictures only when asked (--pictures)"
    summary = read_csv(tmp_path / 'summary.csv')
    assert summary['maps'].tolist() == [10, 20] and summary['alive'].tolist() == [5, 10], 'one row per run'
    assert '| 10 | 1 |' in proc.stdout and 'time to success' in proc.stdout, 'mean ± std per MAP count'


def test_a_sweep_draws_each_runs_pictures_when_asked_and_spreads_only_several_runs(tmp_path: Path) -> None:
    """--pictures: each run's plots and animation too. Time to success of one run that got there is that
    time, with no ± of a spread that one run cannot have."""
    # 18 s: seed 0 reaches R_c >= 95 % connected at 16.8 s, seed 1 not yet
    proc = sim('--maps', '90', '--seed', '0,1', '--duration', '18', '--pictures', '--out', str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    for k in (0, 1):
        assert (tmp_path / f'maps90_seed{k}' / 'formation.gif').exists()
        assert (tmp_path / f'maps90_seed{k}' / 'coverage.png').exists()
    reached = read_csv(tmp_path / 'summary.csv')['time_to_success_s']
    assert int(np.sum(np.isfinite(reached))) == 1, reached
    row = next(line for line in proc.stdout.splitlines() if line.startswith('| 90 |'))
    assert re.search(r'\| [\d.]+ s \(1/2\) \|$', row), row


def test_same_seed_same_run(tmp_path: Path) -> None:
    for name in ('a', 'b'):
        assert sim('--maps', '8', '--duration', '2', '--out', str(tmp_path / name)).returncode == 0
    assert (tmp_path / 'a' / 'trajectory.csv').read_bytes() == (tmp_path / 'b' / 'trajectory.csv').read_bytes()


@pytest.mark.parametrize('args, says', [
    (('sim', '--out', '{file}', '--duration', '1'), 'exists and is not a folder'),
    (('sim', '--out', '{file}/run', '--duration', '1'), 'cannot create'),
    (('up', '--out', '{file}/run', '--duration', '1'), 'cannot create'),
    (('run', '--out', '{file}/run'), 'cannot create'),
    (('run', '--batch', '--out', '{file}/run'), 'cannot create'),
    (('paper', '--out', '{file}'), 'exists and is not a folder'),
    (('paper', '--out', '{folder}/p', '--docs'), 'give one'),
    (('sim', '--scenario', '{folder}'), 'cannot read the scenario'),
    (('sim', '--scenario', sys.executable), 'not a text file'),
    (('up', '--domain-id', '233'), 'expected an integer from 0 to 232'),
    (('topics', '--domain-id', '-1'), 'expected an integer from 0 to 232'),
    (('echo', 'map 3/state'), 'not a valid topic name'),
    (('echo', '/a//b'), 'not a valid topic name'),
    (('sim', '--fail-at', '5', '--out', '{folder}/run'), '--fail-at needs --fail-fraction'),
    (('up', '--fail-at', '5', '--out', '{folder}/run'), '--fail-at needs --fail-fraction'),
    (('sim', '--duration', '10', '--fail-at', '18', '--fail-fraction', '0.3', '--out', '{folder}/run'),
     'is not before the end of the run (10 s)'),
    (('paper', '--seeds', '0', '--out', '{folder}/figures'), 'expected a positive integer'),
    (('sim', '--maps', '40,0', '--out', '{folder}/run'), 'expected positive integers'),
    (('up', '--agents-per-process', '0', '--out', '{folder}/run'), 'expected a positive integer'),
    (('up', '--maps', '40,60', '--out', '{folder}/run'), 'argument --maps: expected a positive integer'),
    (('up', '--seed', '0,1', '--out', '{folder}/run'), 'argument --seed: expected a non-negative integer'),
    (('replay', '{folder}', '--agent', '-1'), 'expected a non-negative integer'),
    (('replay', '{folder}', '--agent', '3', '--tolerance', '-0.5'), 'expected a non-negative finite number'),
    (('up', '--listen', '192.0.2.77', '--out', '{folder}/run'), 'is not an address of this host'),
    (('up', '--listen', 'myhost', '--out', '{folder}/run'), 'expected an IPv4 address'),
    (('up', '--agents-here', '5', '--out', '{folder}/run'), 'give --listen'),
    (('up', '--listen', '127.0.0.1', '--agents-here', '95', '--out', '{folder}/run'), 'the run has 90 MAPs'),
    (('agents', '--join', 'myhost', '--ids', '3', '--out', '{folder}/run'), 'expected HOST:PORT'),
    (('agents', '--join', '127.0.0.1:11900', '--ids', '5-3', '--out', '{folder}/run'), 'ranges low-high'),
    (('agents', '--join', '127.0.0.1:11811', '--ids', '3', '--timeout', '1', '--out', '{folder}/run'),
     'no run answers at 127.0.0.1:11811'),
    (('sim', '--map', '40'), 'sim: unrecognized arguments: --map 40'),
    (('sim', '--maps', '60,', '--out', '{folder}/run'), "got '60,' (an empty item)"),
    (('sim', '--duration', '0.05', '--out', '{folder}/run'), 'sim: --duration 0.05 s is shorter than one step'),
    (('sim', '--duration', '1e9', '--out', '{folder}/run'), 'sim: 1e+09 s is 1e+10 steps of 90 MAPs: their trajectory'),
    (('run', '--batch', '--duration', '0.05', '--out', '{folder}/run'), 'run: --duration 0.05 s'),
    (('view', '{golden}', '--port', '99999'), 'view: argument --port: expected an integer from 1 to 65535'),
    (('run', '--view', '70000', '--out', '{folder}/run'), 'run: argument --view: expected an integer from 1'),
    (('replay', '{golden}', '--agent', '2', '--set', 'flock.cl=3'), "no agent parameter 'flock.cl'; did you mean c1?"),
    (('replay', '{golden}', '--agent', '2', '--set', 'c1=abc'), "replay: --set c1: expected a number, got 'abc'"),
    (('replay', '{golden}', '--agent', '2', '--set', 'd=30'), 'replay: --set d: must be below --set r'),
    (('replay', '{golden}', '--agent', '2', '--plot', '{folder}/du.png'), '--plot draws the difference that --set'),
])
def test_a_user_mistake_is_one_line_and_exit_2(tmp_path: Path, args: tuple[str, ...], says: str) -> None:
    """Caught before any work starts: a bad --out found only at the end would lose the run."""
    (tmp_path / 'plain').write_text('not a folder')
    filled = [a.format(file=tmp_path / 'plain', folder=tmp_path, golden=GOLDEN_BAG) for a in args]
    proc = subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', *filled], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and says in proc.stderr, proc.stderr
    assert proc.stderr.count('uav-flock:') == 1, f'the program is named once: {proc.stderr}'
    assert list(tmp_path.iterdir()) == [tmp_path / 'plain'], 'nothing written'


def test_the_wrapper_help_names_every_command() -> None:
    """README sends users to `./uav-flock --help` for every command: it must not fall behind the CLI."""
    from uav_flock_tools.cli import build_parser
    wrapper = Path(__file__).resolve().parents[2] / 'uav-flock'
    shown = subprocess.run([str(wrapper), '--help'], capture_output=True, text=True, timeout=30).stdout
    sub = next(a for a in build_parser()._actions if a.dest == 'command')
    missing = [c for c in sub.choices if not re.search(rf'^  {c} +\S', shown, re.MULTILINE)]
    assert not missing, f'./uav-flock --help has no line saying what {missing} do'


def test_ctrl_c_ends_the_paper_sweep_without_running_the_rest(tmp_path: Path) -> None:
    """Ctrl-C reaches the whole process group, as in a terminal. The sweep's hundreds of runs take minutes on two cores:
    the runs not yet started must be dropped, not run to the end before the exit."""
    log = tmp_path / 'stderr.txt'
    with open(log, 'w') as err:
        # As a terminal's foreground job: a suite started in the background of a shell without job control
        # inherits SIGINT ignored, and Python then keeps ignoring it.
        proc = subprocess.Popen([sys.executable, '-m', 'uav_flock_tools.cli', 'paper', '--out', str(tmp_path / 'p')],
                                stdout=subprocess.DEVNULL, stderr=err, start_new_session=True,
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 120
        while not re.search(r'paper runs:.* [1-9]\d*/\d+', log.read_text()):
            assert time.monotonic() < deadline and proc.poll() is None, f'the sweep never started: {log.read_text()}'
            time.sleep(0.2)
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(timeout=60)  # the runs left would take minutes
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130, log.read_text()
    assert log.read_text().strip().splitlines()[-1].endswith('uav-flock: interrupted')
    assert not (tmp_path / 'p' / 'results.md').exists()


def test_kill_on_an_ended_run_spares_processes_that_now_hold_its_pids(tmp_path: Path) -> None:
    """Pids are reused once a run has ended: only a living agent of that very run may be SIGKILLed, and asking
    for MAPs that are not alive is one line and exit 2, not a quiet no-op."""
    bystander = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'])
    try:
        (tmp_path / 'pids.json').write_text(f'{{"0": {bystander.pid}, "1": {bystander.pid}}}')
        for how, says in ((('--ids', '0,1'), 'MAPs 0, 1 are not alive'), (('--fraction', '1'), 'nothing to kill')):
            done = subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'kill', '--run', str(tmp_path), *how],
                                  capture_output=True, text=True, timeout=60)
            assert done.returncode == 2 and says in done.stderr and done.stderr.count('\n') == 1, \
                done.stdout + done.stderr
            assert bystander.poll() is None, 'kill --run SIGKILLed a process that is not an agent of the run'
    finally:
        bystander.kill()
        bystander.wait()


SWALLOWED = '''
import os, signal, time, weakref
from uav_flock_tools import cli
cli.install_interrupts()
class Thing: pass
thing = Thing()
def callback(_):
    os.kill(os.getpid(), signal.SIGTERM)
    sum(range(100000))  # the handler runs in here, where Python swallows its exception
ref = weakref.ref(thing, callback)
try:
    del thing
    time.sleep(5)
    print('carried on')
except KeyboardInterrupt:
    print('interrupted')
'''


def test_an_interrupt_swallowed_in_a_callback_is_raised_again() -> None:
    """`kill PID` landing in a weakref callback (importlib has them) was lost: a replay ran on to its end."""
    done = subprocess.run([sys.executable, '-c', SWALLOWED], capture_output=True, text=True, timeout=60)
    assert done.stdout.strip() == 'interrupted', done.stdout + done.stderr
    assert 'Exception ignored' not in done.stderr, done.stderr


MID_CONSTRUCTION = '''
import os, signal
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions
from uav_flock_tools.cli import install_interrupts
from uav_flock_ros.executors import signals_deferred
install_interrupts()
context = rclpy.Context()
built = None
try:
    with signals_deferred():
        rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
        os.kill(os.getpid(), signal.SIGTERM)  # lands where an rclpy constructor runs
        built = SingleThreadedExecutor(context=context)
    print('not interrupted')
except KeyboardInterrupt:
    print('interrupted after the executor was built' if built is not None else 'interrupted mid-construction')
finally:
    rclpy.try_shutdown(context=context)
'''


def test_a_signal_during_rclpy_construction_is_handled_after_it() -> None:
    """`kill PID` while replay made its executor left a half-made one whose __del__ printed rclpy's traceback."""
    done = subprocess.run([sys.executable, '-c', MID_CONSTRUCTION], capture_output=True, text=True, timeout=60)
    assert done.stdout.strip() == 'interrupted after the executor was built', done.stdout + done.stderr
    assert 'Exception ignored' not in done.stderr and 'Traceback' not in done.stderr, done.stderr


@pytest.mark.parametrize('program, says', [('ros2', './uav-flock topics'), ('no-such-program', 'no such program')])
def test_exec_of_a_program_that_is_not_there_says_what_to_use(program: str, says: str) -> None:
    wrapper = Path(__file__).resolve().parents[2] / 'uav-flock'
    done = subprocess.run([str(wrapper), 'exec', program, 'topic', 'list'], capture_output=True, text=True, timeout=120,
                          env={**os.environ, 'UAV_FLOCK_QUIET': '1'})
    assert done.returncode == 127 and len(done.stderr.strip().splitlines()) == 1 and says in done.stderr, done.stderr


def test_topics_are_listed_in_natural_order() -> None:
    from uav_flock_tools.echo import natural
    names = ['/map_10/state', '/map_2/state', '/metrics', '/map_1/cmd', '/map_2/cmd']
    assert sorted(names, key=natural) == ['/map_1/cmd', '/map_2/cmd', '/map_2/state', '/map_10/state', '/metrics']


def test_floor_names_the_lb_of_any_scenario_and_sim_says_when_maps_are_below_it(tmp_path: Path) -> None:
    from world_sim.core import layouts
    from world_sim.shipped import load_scenario
    lb = layouts.floor(load_scenario('paper')).total
    floor = subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'floor'], capture_output=True, text=True,
                           timeout=60)
    assert floor.returncode == 0 and f'LB = {lb} MAPs' in floor.stdout, floor.stdout + floor.stderr
    below = sim('--maps', str(lb - 1), '--duration', '1', '--out', str(tmp_path / 'below'))
    above = sim('--maps', str(lb), '--duration', '1', '--out', str(tmp_path / 'above'))
    assert f'below the floor of this layout, LB = {lb} MAPs' in below.stderr and 'note:' not in above.stderr


def test_paper_names_the_command_that_ran_and_each_path_once(tmp_path: Path, paper_scenario_path: str) -> None:
    out, short = tmp_path / 'paper1', tmp_path / 'short.yaml'  # the paper's layout, 20 s runs: naming, not figures
    short.write_text(re.sub(r'(?m)^duration:.*$', 'duration: 20.0', Path(paper_scenario_path).read_text()))
    (tmp_path / 'shorter.yaml').write_text(short.read_text().replace('duration: 20.0', 'duration: 3.0'))
    refused = subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'paper', '--scenario',
                              str(tmp_path / 'shorter.yaml'), '--out', str(tmp_path / 'no')],
                             capture_output=True, text=True)
    assert refused.returncode == 2 and len(refused.stderr.strip().splitlines()) == 1 and 'before the failure' in \
        refused.stderr and not (tmp_path / 'no').exists(), refused.stderr
    args = ['paper', '--scenario', str(short), '--seeds', '1', '--no-ablation', '--layouts', '0', '--out', str(out)]
    proc = subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', *args], capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr
    results = (out / 'results.md').read_text()
    assert f'Generated by `./uav-flock {" ".join(args)}`' in results, results[:400]
    assert proc.stdout.count(str(out / 'results.md')) == 1, proc.stdout


def test_a_run_folder_says_what_ran_and_flies_it_again_to_the_bit(tmp_path: Path) -> None:
    """Every override of the command line (MAPs, seed, duration, failures, the vehicle) is in the folder's
    scenario.yaml; `sim --scenario` of that file flies the same run, byte for byte, and provenance.json names the
    command line, the seed, the vehicle, the version and the commit."""
    args = ['--scenario', 'drift', '--maps', '40', '--seed', '3', '--duration', '6', '--fail-at', '3',
            '--fail-fraction', '0.2', '--vehicle', 'multirotor']
    assert sim(*args, '--out', str(tmp_path / 'a')).returncode == 0
    said = json.loads((tmp_path / 'a' / 'provenance.json').read_text())
    assert said['command'] == ['uav-flock', 'sim', *args, '--out', str(tmp_path / 'a')]
    assert (said['seed'], said['maps'], said['vehicle'], said['duration']) == (3, 40, 'multirotor', 6.0)
    assert said['uav_flock'] == '0.1.0' and re.fullmatch(r'[0-9a-f]{40}(\+dirty)?', said['commit']), said
    from uav_flock_tools import provenance
    assert re.fullmatch(r'[0-9a-f]{16}', said['code']) and said['code'] == provenance.code(), said
    again = sim('--scenario', str(tmp_path / 'a' / 'scenario.yaml'), '--out', str(tmp_path / 'b'))
    assert again.returncode == 0, again.stderr
    for name in ('metrics.csv', 'trajectory.csv', 'failures.json'):
        assert (tmp_path / 'a' / name).read_bytes() == (tmp_path / 'b' / name).read_bytes(), name
    other = sim('--scenario', 'drift', '--maps', '40', '--seed', '3', '--duration', '6',
                    '--out', str(tmp_path / 'c'))
    assert (tmp_path / 'a' / 'trajectory.csv').read_bytes() != (tmp_path / 'c' / 'trajectory.csv').read_bytes(), \
        'the failure changes the run: the rerun had it from the file'


@pytest.mark.parametrize('vehicle, first', [('ideal', "vehicle: ideal: the paper's double integrator"),
                                            ('multirotor', 'vehicle: multirotor: 15 m/s')])
def test_a_run_names_its_vehicle_first(tmp_path: Path, vehicle: str, first: str) -> None:
    """The same layout succeeds at 16.8 s on one vehicle and 30.2 s on the other: the first line says which flew."""
    done = sim('--maps', '20', '--duration', '0.5', '--vehicle', vehicle, '--out', str(tmp_path / 'r'))
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines()[0].startswith(first), done.stdout
    assert json.loads((tmp_path / 'r' / 'provenance.json').read_text())['vehicle'] == vehicle


@pytest.mark.parametrize('survey, noted', [('given', True), ('online', False)])
def test_moving_clusters_the_maps_are_never_told_of_get_a_note(tmp_path: Path, survey: str, noted: bool) -> None:
    """A cluster that drifts under `survey: given`: its MAPs stay where its users were, and coverage falls as it
    leaves; one line says so before the run, none when the MAPs follow it."""
    import yaml
    from world_sim.core.scenario import to_doc
    from world_sim.shipped import load_scenario
    doc = to_doc(load_scenario('paper'))
    doc['users']['clusters'][0]['velocity'] = [1.0, 0.0]
    doc['users']['survey'] = survey
    (tmp_path / 's.yaml').write_text(yaml.safe_dump(doc))
    done = sim('--scenario', str(tmp_path / 's.yaml'), '--duration', '0.2', '--out', str(tmp_path / 'r'))
    assert done.returncode == 0, done.stderr
    assert ('survey: online' in done.stderr) == noted, done.stderr
