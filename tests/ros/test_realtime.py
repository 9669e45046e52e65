"""Realtime sync: the world steps on a wall-clock timer and every MAP flies on the latest data it has."""
from __future__ import annotations

import dataclasses
import re
import subprocess
import time
from pathlib import Path

import numpy as np
import yaml
from helpers.runs import cli, dropped_ids, kill_during, up, wait_for_line
from uav_agent.core.links import LOST, Links, deliver
from world_sim.core.records import read_csv
from world_sim.core.scenario import to_doc
from world_sim.shipped import load_scenario

PROGRESS = re.compile(r't = +([\d.]+) s .* fresh commands (\d+) %')


def progress(lines: list[str]) -> list[tuple[float, int]]:
    return [(float(m[1]), int(m[2])) for m in map(PROGRESS.search, lines) if m]


def test_realtime_run_keeps_its_pace_and_flies_like_sim(tmp_path: Path, ros_env: dict[str, str]) -> None:
    args = ('--maps', '12', '--seed', '0', '--duration', '12')
    proc = up(*args, '--sync', 'realtime', '--rate', '2', '--out', str(tmp_path / 'up'), env=ros_env)
    stamped: list[tuple[float, str]] = []
    assert proc.stdout is not None
    for line in proc.stdout:
        stamped.append((time.monotonic(), line))
    assert proc.wait(timeout=60) == 0, ''.join(line for _, line in stamped)
    lines = [line for _, line in stamped]
    assert 'realtime x2' in next(line for line in lines if not line.startswith('note:'))  # 12 MAPs: below the floor
    seen = progress(lines)
    assert [t for t, _ in seen] == [float(t) for t in range(13)], 'a progress line per simulated second'
    assert all(0 <= fresh <= 100 for _, fresh in seen)
    # The timer sets the pace: 11 simulated seconds between the first and the last line at rate 2 take
    # 5.5 s of wall time at least (a lower bound: the world may fall behind its timer, never ahead of it).
    wall = [when for when, line in stamped if PROGRESS.search(line)]
    assert wall[-1] - wall[0] >= 0.9 * 11 / 2, f'{wall[-1] - wall[0]:.2f} s of wall time for 11 simulated s'

    m = read_csv(tmp_path / 'up' / 'metrics.csv')
    assert np.array_equal(m['step'], np.arange(121)) and np.allclose(m['t'], 0.1 * m['step'])
    t = read_csv(tmp_path / 'up' / 'trajectory.csv')
    assert len(t['step']) == 12 * 121 and all(np.all(np.isfinite(t[c])) for c in ('x', 'y', 'vx', 'vy'))
    assert cli('sim', *args, '--out', str(tmp_path / 'sim')).returncode == 0
    s = read_csv(tmp_path / 'sim' / 'metrics.csv')
    # Commands computed on neighbour states a step old, and held while late, change the path a little,
    # not where the formation goes.
    assert abs(m['coverage_ratio'][-1] - s['coverage_ratio'][-1]) <= 0.10, (m['coverage_ratio'][-1],
                                                                            s['coverage_ratio'][-1])
    a, b = read_csv(tmp_path / 'up' / 'trajectory.csv'), read_csv(tmp_path / 'sim' / 'trajectory.csv')
    gap = np.hypot(a['x'] - b['x'], a['y'] - b['y'])
    assert gap.max() > 1e-6, 'realtime is not lockstep: MAPs act on neighbour states of an earlier step'
    assert np.median(gap[a['step'] == 120]) < 10.0, f'median gap to sim at the end {np.median(gap):.1f} m'


def test_realtime_drops_killed_agents_and_goes_on(tmp_path: Path, ros_env: dict[str, str]) -> None:
    run = tmp_path / 'up'
    proc = up('--maps', '10', '--seed', '1', '--duration', '20', '--sync', 'realtime', '--rate', '2',
              '--out', str(run), env=ros_env)
    seen, rest = kill_during(proc, str(run), '2,5', 't =   3.0 s')
    assert proc.returncode == 0, seen + rest
    assert dropped_ids(seen) == [2, 5], seen
    m = read_csv(run / 'metrics.csv')
    assert m['t'][-1] == 20.0 and m['alive'][0] == 10 and m['alive'][-1] == 8
    t = read_csv(run / 'trajectory.csv')
    assert set(t['id'][t['step'] == t['step'].max()].astype(int).tolist()) == set(range(10)) - {2, 5}


def agent(ids: str, env: dict[str, str], *ros_args: str) -> subprocess.Popen[str]:
    from uav_flock_tools.spawn import executable
    return subprocess.Popen([executable('uav_agent', 'uav_agent_node'), '--ids', ids, '--ros-args', *ros_args],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def test_agents_wait_for_a_world_that_comes_late(tmp_path: Path, ros_env: dict[str, str]) -> None:
    """Agents started by hand before world_sim wait for it (many processes on few cores start slowly), making
    their DDS participant anew while they have not seen it (renew_unseen, here 3 s: three times, the most), and
    the participant they end with flies the run.

    The world is started the plain ROS way, without a scenario parameter: it runs the shipped paper scenario.
    """
    waiting = agent('0,1', ros_env, '-p', 'renew_unseen:=3.0')
    impatient = agent('5', {**ros_env, 'ROS_DOMAIN_ID': str((int(ros_env['ROS_DOMAIN_ID']) + 50) % 101 + 1)},
                      '-p', 'world_start_timeout:=2.0')
    try:
        said, _ = impatient.communicate(timeout=60)
        assert impatient.returncode == 1 and 'no world_sim appeared within' in said, said
        time.sleep(12.0)  # longer than an agent waits for a world it has already seen
        assert waiting.poll() is None, 'an agent must keep waiting for a world that has not appeared yet'
        from uav_flock_tools.spawn import executable
        world = subprocess.run([executable('world_sim', 'world_sim_node'), '--ros-args', '-p', 'maps:=2',
                                '-p', 'duration:=1.0', '-p', f'out:={tmp_path}'], env=ros_env, capture_output=True,
                               text=True, timeout=120)
        assert world.returncode == 0, world.stdout + world.stderr
        assert read_csv(tmp_path / 'metrics.csv')['t'][-1] == 1.0
        # The run's normal end reaches the agents: they stop on it, exit 0, and log no error.
        said, _ = waiting.communicate(timeout=30)
        assert waiting.returncode == 0 and 'world_sim finished the run after 10 steps' in said, said
        assert '[ERROR]' not in said, said
        renewals = re.findall(r'no world_sim seen in 3 s: the DDS participant of MAPs \[0, 1\] made anew \((\d) of 3\)',
                              said)
        assert renewals == ['1', '2', '3'], said
        assert 'MAP 0: waiting for world_sim (ROS_DOMAIN_ID=' in said, 'a node waiting for its world says so'
    finally:
        for p in (waiting, impatient):
            if p.poll() is None:
                p.terminate()
                p.communicate(timeout=30)


def test_bad_node_parameters_and_sync_options_are_one_line_errors(ros_env: dict[str, str]) -> None:
    bad = agent('0', ros_env, '-p', 'sync:=warp')
    said, _ = bad.communicate(timeout=60)
    assert bad.returncode == 2 and said.strip().count('\n') == 0 and "parameter sync" in said, said
    from uav_flock_tools.spawn import executable
    for node, args in (('uav_agent_node', ['--ids', '0', '--ros-args', '-p', 'r:=far']),  # r is a float
                       ('uav_agent_node', ['--ids', '0', '--ros-args', '-p', 'r:=-24.0']),
                       ('uav_agent_node', ['--ids', '0', '--ros-args', '-p', 'n0:=20']),  # above n1
                       ('uav_agent_node', ['--ids', '0', '--ros-args', '-p', 'edge_choice:=random']),
                       ('uav_agent_node', ['--ids', '0', '--ros-args', '-p', 'hysteresis:=-1.0']),
                       ('world_sim_node', ['--ros-args', '-p', 'maps:=many']),
                       ('world_sim_node', ['--ros-args', '-p', 'seed:=-5']),  # not the -1 that means the scenario's
                       ('world_sim_node', ['--ros-args', '-p', 'duration:=-5.0']),
                       ('world_sim_node', ['--ros-args', '-p', 'scenario:=no_such_scenario']),
                       ('uav_agent_node', ['--ids', '3', '--ros-args', '--params-file', 'runs/nosuch.yaml']),
                       ('world_sim_node', ['--ros-args', '--params-file', 'runs/nosuch.yaml']),
                       ('uav_agent_node', ['--ids', '3', '--ros-args', '-r'])):  # rcl's own refusal
        pkg = 'uav_agent' if node == 'uav_agent_node' else 'world_sim'
        done = subprocess.run([executable(pkg, node), *args], env=ros_env, capture_output=True, text=True, timeout=60)
        said = (done.stdout + done.stderr).strip()
        assert done.returncode == 2 and said.count('\n') == 0 and 'error:' in said, said
    rate = cli('up', '--maps', '2', '--rate', '2')
    assert rate.returncode == 2 and '--rate' in rate.stderr and 'Traceback' not in rate.stderr, rate.stderr
    sync = cli('up', '--maps', '2', '--sync', 'warp')
    assert sync.returncode == 2 and 'Traceback' not in sync.stderr, sync.stderr


def test_a_bad_p_beside_a_params_file_setting_it_is_one_line(tmp_path: Path, ros_env: dict[str, str]) -> None:
    """rcl keeps a --params-file's value and drops a -p of the wrong type without a word: the node says so."""
    from uav_flock_tools.spawn import executable
    params = tmp_path / 'params.yaml'
    params.write_text('/**:\n  ros__parameters:\n    c1: 0.4\n    duration: 3.0\n')
    for pkg, node, args in (('uav_agent', 'uav_agent_node', ['--ids', '3', '--ros-args', '--params-file', str(params),
                                                            '-p', 'c1:=abc']),
                            ('world_sim', 'world_sim_node', ['--ros-args', '--params-file', str(params),
                                                            '-p', 'duration:=long'])):
        done = subprocess.run([executable(pkg, node), *args], env=ros_env, capture_output=True, text=True, timeout=60)
        said = (done.stdout + done.stderr).strip()
        assert done.returncode == 2 and said.count('\n') == 0 and 'did not take' in said, said


def test_a_start_too_slow_for_its_timeout_names_the_option_that_waits_longer(tmp_path: Path) -> None:
    """`up --maps 2000` on two cores outlasted the fixed start wait: --start-timeout sets it, and the failure
    names it."""
    # Every MAP left to agents of other hosts, which never come: the wait is all there is.
    done = cli('up', '--maps', '3', '--duration', '1', '--listen', '127.0.0.1', '--agents-here', '0',
               '--start-timeout', '2', '--out', str(tmp_path / 'st'))
    assert done.returncode == 1, done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert 'only 0 of 3 MAPs appeared within 2 s' in last and 'up --start-timeout SECONDS' in last, last
    bad = cli('up', '--maps', '3', '--start-timeout', '0')
    assert bad.returncode == 2 and '--start-timeout' in bad.stderr and 'Traceback' not in bad.stderr, bad.stderr


def test_sigterm_ends_a_stepping_world_in_order(tmp_path: Path, ros_env: dict[str, str]) -> None:
    """`kill PID` on world_sim mid-run: records written, no fatal callback error from a signal raised inside one."""
    from uav_flock_tools.spawn import executable
    for attempt in range(3):  # steps run back to back: the signal lands inside a callback most of the time
        out = tmp_path / str(attempt)
        maps = agent('0,1,2', ros_env)
        world = subprocess.Popen([executable('world_sim', 'world_sim_node'), '--ros-args', '-p', 'maps:=3',
                                  '-p', 'duration:=600.0', '-p', f'out:={out}'], env=ros_env,
                                 stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            seen = wait_for_line(world, 't =   2.0 s', 120)
            world.terminate()
            said = ''.join(seen) + world.communicate(timeout=30)[0]
            assert world.returncode == 1, said  # interrupted, not finished
            assert 'FATAL' not in said and 'Traceback' not in said, said
            assert read_csv(out / 'metrics.csv')['t'][-1] >= 2.0
        finally:
            for p in (world, maps):
                if p.poll() is None:
                    p.terminate()  # not SIGKILL: a killed participant leaves its files in /dev/shm
                p.communicate(timeout=30)


def test_a_pace_the_machine_cannot_keep_is_reported_once(tmp_path: Path, ros_env: dict[str, str]) -> None:
    done = cli('up', '--maps', '3', '--duration', '6', '--sync', 'realtime', '--rate', '200', '--out', str(tmp_path),
               env=ros_env)
    assert done.returncode == 0, done.stdout + done.stderr
    said = [line for line in done.stdout.splitlines() if 'the run goes slower than asked' in line]
    assert len(said) == 1 and 'asks for 2000 steps/s' in said[0], done.stdout
    assert '--agents-per-process' in said[0] and '--rate' in said[0], 'it says what helps'


def test_a_realtime_channel_discards_exactly_the_states_its_decision_names(tmp_path: Path, ros_env: dict[str, str]) -> None:
    """Over DDS in realtime, each neighbour state that arrives goes through the channel's one decision
    (links.deliver, by ear.hear): the lost ones are dropped, the others held until they may be used. Every
    arrival each MAP logged is decided again here."""
    doc = to_doc(dataclasses.replace(load_scenario('paper'), seed=5))
    doc['links'] = {'loss': 0.4, 'burst': 3, 'latency': 1, 'ttl': 5}
    (tmp_path / 'lossy.yaml').write_text(yaml.safe_dump(doc))
    done = cli('up', '--scenario', str(tmp_path / 'lossy.yaml'), '--maps', '12', '--duration', '6', '--sync', 'realtime',
               '--rate', '2', '--out', str(tmp_path / 'up'), env=ros_env)
    assert done.returncode == 0, done.stdout + done.stderr
    logs = sorted((tmp_path / 'up' / 'links').glob('map_*.csv'))
    assert len(logs) == 12, 'every MAP logs what arrived'
    links, decided = Links(loss=0.4, burst=3.0, latency=1, ttl=5), 0
    lost = 0
    for log in logs:
        rows = np.atleast_2d(np.loadtxt(log, delimiter=',', skiprows=1))
        rx = int(log.stem.split('_')[1])
        for row in rows:
            again = deliver(links, 5, int(row[0]), np.array([rx]), np.array([int(row[1])]), row[None, 2:5], row[None, 5:8], 24.0)[0]
            assert bool(row[8]) == (again != LOST), f'MAP {rx}: the state of step {int(row[0])} from {int(row[1])}'
        decided += len(rows)
        lost += int((rows[:, 8] == 0).sum())
    assert decided > 100 and 0 < lost < decided, (decided, lost)
