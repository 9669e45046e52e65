"""The distributed system: real processes over DDS, compared with the batch simulator (the oracle)."""
from __future__ import annotations

import json
import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.bags import assert_nothing_lost
from helpers.runs import cli, dead, dropped_ids, helper, kill_during, shm_entries, up, wait_for_line
from uav_flock_tools.domains import claim_domain
from world_sim.core.records import read_csv


def test_lockstep_equals_the_batch_simulator_over_a_lossy_late_channel(tmp_path: Path, ros_env: dict[str, str]) -> None:
    """Each MAP decides which neighbour states it hears, and when it may use them, as the batch simulator does
    for it: losses by distance and in bursts, two steps of latency, a failure, MAPs packed in processes."""
    drawn = cli('layouts', '--count', '1', '--clusters', '3', '--seed', '4', '--out', str(tmp_path / 'layouts'))
    assert drawn.returncode == 0, drawn.stderr
    doc = yaml.safe_load((tmp_path / 'layouts' / 'layout-000.yaml').read_text())
    doc['links'] = {'delivery': 'alpha', 'z1': 0.8, 'loss': 0.3, 'burst': 5, 'latency': 2, 'ttl': 6}
    (tmp_path / 'lossy.yaml').write_text(yaml.safe_dump(doc))
    args = ('--maps', '24', '--duration', '8', '--fail-at', '4', '--fail-fraction', '0.2')
    lossy = ('--scenario', str(tmp_path / 'lossy.yaml'), *args)
    distributed = cli('up', *lossy, '--agents-per-process', '6', '--out', str(tmp_path / 'up'), env=ros_env)
    assert distributed.returncode == 0, distributed.stdout + distributed.stderr
    batch = cli('sim', *lossy, '--out', str(tmp_path / 'sim'))
    assert batch.returncode == 0, batch.stderr
    assert (tmp_path / 'up' / 'trajectory.csv').read_bytes() == (tmp_path / 'sim' / 'trajectory.csv').read_bytes()
    # Both say the radio they fly under, and end with the same account of what the MAPs heard.
    radio = "delivered with the paper's alpha (falling from 0.8 r to r), 30 % lost on top in bursts of 5 steps"
    assert radio in distributed.stdout and radio in batch.stdout, distributed.stdout
    heard = [line.split('usable graph')[1] for line in distributed.stdout.splitlines() if 'usable graph' in line]
    assert heard and heard == [line.split('usable graph')[1] for line in batch.stdout.splitlines()
                               if 'usable graph' in line], distributed.stdout + batch.stdout
    perfect = ('--scenario', str(tmp_path / 'layouts' / 'layout-000.yaml'), *args)
    assert cli('sim', *perfect, '--out', str(tmp_path / 'perfect')).returncode == 0
    assert (tmp_path / 'perfect' / 'trajectory.csv').read_bytes() != (tmp_path / 'sim' / 'trajectory.csv').read_bytes(), \
        'the channel changes the run'


@pytest.mark.parametrize('model, safety', [('multirotor', 'rules'), ('multirotor', 'filter'), ('x500', 'rules')])
def test_lockstep_equals_the_batch_simulator_on_a_multirotor(tmp_path: Path, ros_env: dict[str, str],
                                                            model: str, safety: str) -> None:
    """The world owns the vehicle (lag, limits, gusts, GNSS error): the MAPs decide from the estimate it tells
    them, as the batch simulator's do, to the bit; the records keep the truth and the estimate apart. Under
    today's rules and under the safety filter, whose QP each MAP's node solves for itself; and on crazyflow's
    X500, whose world node is a process set up for it."""
    drawn = cli('layouts', '--count', '1', '--clusters', '3', '--seed', '4', '--out', str(tmp_path / 'layouts'))
    assert drawn.returncode == 0, drawn.stderr
    doc = yaml.safe_load((tmp_path / 'layouts' / 'layout-000.yaml').read_text())
    # A separation wide enough that the MAPs brake on the broadcasts of their traffic receivers within the 8 s
    # (rule 'traffic': the run differs with it off), which the world tells each MAP in its sensing.
    doc['vehicle'] = {'model': model, 'separation': 15.0, 'wind': {'speed': 6.0, 'gust': 2.0},
                      'gnss': {'sigma': 2.0, 'own': 0.8}}
    doc.setdefault('policies', {})['safety'] = safety
    (tmp_path / 'multirotor.yaml').write_text(yaml.safe_dump(doc))
    args = ('--scenario', str(tmp_path / 'multirotor.yaml'), '--maps', '24', '--duration', '8', '--fail-at', '4',
            '--fail-fraction', '0.2')
    distributed = cli('up', *args, '--agents-per-process', '6', '--out', str(tmp_path / 'up'), env=ros_env)
    assert distributed.returncode == 0, distributed.stdout + distributed.stderr
    batch = cli('sim', *args, '--out', str(tmp_path / 'sim'))
    assert batch.returncode == 0, batch.stderr
    for name in ('trajectory.csv', 'metrics.csv'):
        assert (tmp_path / 'up' / name).read_bytes() == (tmp_path / 'sim' / name).read_bytes(), name
    counts = read_csv(tmp_path / 'up' / 'metrics.csv')
    assert counts['held'].sum() + counts['relaxed'].sum() == 0, 'no link is protected under the rules, nor here ' \
        'under the filter: this run, below its floor, serves no cluster (its link rows: tests/unit/test_safety.py)'
    if safety == 'filter':  # each node's QP flew it: the same run under the rules is another
        doc['policies']['safety'] = 'rules'
        (tmp_path / 'rules.yaml').write_text(yaml.safe_dump(doc))
        rules = cli('sim', '--scenario', str(tmp_path / 'rules.yaml'), *args[2:], '--out', str(tmp_path / 'rules'))
        assert rules.returncode == 0, rules.stderr
        assert (tmp_path / 'rules' / 'trajectory.csv').read_bytes() != (tmp_path / 'up' / 'trajectory.csv').read_bytes()
    flown = [yaml.safe_load((tmp_path / run / 'scenario.yaml').read_text()) for run in ('up', 'sim')]
    assert flown[0] == flown[1] and flown[0]['policies']['safety'] == safety, 'each folder says what it flew'
    assert f'vehicle: {model}: 15 m/s' in distributed.stdout and f'vehicle: {model}: 15 m/s' in batch.stdout
    flight = [line.split('least distance')[1] for line in distributed.stdout.splitlines() if 'least distance' in line]
    assert flight and flight == [line.split('least distance')[1] for line in batch.stdout.splitlines()
                                 if 'least distance' in line], distributed.stdout + batch.stdout
    traj = read_csv(tmp_path / 'sim' / 'trajectory.csv')
    assert np.abs(traj['x_est'] - traj['x']).max() > 0.1, 'the MAPs fly on an estimate, not the truth'
    assert (tmp_path / 'sim' / 'flight.png').exists()


def test_packed_agents_give_the_same_run(tmp_path: Path, ros_env: dict[str, str]) -> None:
    """Also with a scheduled failure: a failed MAP sharing its process with live ones falls silent. Over the
    Fast DDS discovery server that `up` uses beyond 30 processes, forced here on a small run."""
    args = ('--maps', '9', '--seed', '1', '--duration', '4', '--fail-at', '2', '--fail-fraction', '0.3')
    packed = cli('up', *args, '--agents-per-process', '4', '--discovery', 'server', '--out', str(tmp_path / 'up'),
                 env=ros_env)
    assert packed.returncode == 0, packed.stdout + packed.stderr
    assert 'discovery server 127.0.0.1:' in packed.stdout
    assert json.loads((tmp_path / 'up' / 'run.json').read_text())['discovery_server'].startswith('127.0.0.1:')
    assert len(set(json.loads((tmp_path / 'up' / 'pids.json').read_text()).values())) == 3
    assert cli('sim', *args, '--out', str(tmp_path / 'sim')).returncode == 0
    assert (tmp_path / 'up' / 'trajectory.csv').read_bytes() == (tmp_path / 'sim' / 'trajectory.csv').read_bytes()


def test_scheduled_failures_sigkill_the_agent_processes(tmp_path: Path, ros_env: dict[str, str]) -> None:
    args = ('--maps', '8', '--seed', '2', '--duration', '20', '--fail-at', '2', '--fail-fraction', '0.25')
    run = tmp_path / 'up'
    proc = up(*args, '--agents-per-process', '1', '--out', str(run), env=ros_env)
    try:
        seen = wait_for_line(proc, '(scheduled)', 120)
        failed = dropped_ids(seen[-1], 'scheduled')
        table = {int(k): v for k, v in json.loads((run / 'pids.json').read_text()).items()}
        t0 = time.monotonic()
        while not all(dead(table[i]) for i in failed) and time.monotonic() - t0 < 5:
            time.sleep(0.05)
        gone = {i for i in table if dead(table[i])}
        running = proc.poll() is None  # the others are ended at the run's end: judge while it goes on
        out, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert running, 'the run ended before the processes could be judged'
    assert len(failed) == 2 and gone == set(failed), f'failed {failed}, processes gone {sorted(gone)}'
    assert proc.returncode == 0, out
    assert cli('sim', *args, '--out', str(tmp_path / 'sim')).returncode == 0
    assert (run / 'trajectory.csv').read_bytes() == (tmp_path / 'sim' / 'trajectory.csv').read_bytes()


def test_a_run_whose_maps_all_fail_goes_on_to_its_end(tmp_path: Path, ros_env: dict[str, str]) -> None:
    """Lockstep with no live MAP left has no command to wait for: the world steps on alone, as `sim` does."""
    args = ('--maps', '3', '--seed', '1', '--duration', '2', '--fail-at', '0.5', '--fail-fraction', '1')
    run = cli('up', *args, '--out', str(tmp_path / 'up'), env=ros_env, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    assert cli('sim', *args, '--out', str(tmp_path / 'sim')).returncode == 0
    for name in ('metrics.csv', 'trajectory.csv'):
        assert (tmp_path / 'up' / name).read_bytes() == (tmp_path / 'sim' / name).read_bytes(), name
    m = read_csv(tmp_path / 'up' / 'metrics.csv')
    assert m['t'][-1] == 2.0 and m['alive'][-1] == 0


def test_a_process_that_makes_its_participant_anew_mid_run_goes_on_where_it_was(tmp_path: Path,
                                                                               ros_env: dict[str, str]) -> None:
    """A process makes its DDS participant anew past step 0 when a connection to a neighbour carries nothing
    (recovery.stuck_midway), or at SIGUSR2, as here: its MAPs carry what they decided and heard to the new one
    (AgentNode.carry), and the lockstep run ends as `sim` flies it, byte for byte. Recorded, its bag holds every
    state and command of the old participant's writers too: they go only once the recorder has them."""
    run = tmp_path / 'up'
    args = ('--scenario', 'drift', '--maps', '12', '--seed', '0', '--duration', '6')
    proc = up(*args, '--agents-per-process', '3', '--record', '--out', str(run), env=ros_env)
    try:
        seen = ''.join(wait_for_line(proc, 't =   2.0 s', 120))
        pids = json.loads((run / 'pids.json').read_text())
        assert pids['3'] == pids['4'] == pids['5'], pids
        os.kill(pids['4'], signal.SIGUSR2)
        rest = proc.communicate(timeout=300)[0]
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, seen + rest
    logs = ''.join(log.read_text(errors='replace') for log in (run / 'logs').glob('agents_*.log'))
    assert 'SIGUSR2: the DDS participant of MAPs [3, 4, 5] made anew (1 of 3)' in logs, logs[-3000:]
    batch = cli('sim', *args, '--out', str(tmp_path / 'sim'))
    assert batch.returncode == 0, batch.stderr
    for name in ('trajectory.csv', 'metrics.csv'):
        assert (run / name).read_bytes() == (tmp_path / 'sim' / name).read_bytes(), name
    assert_nothing_lost(run)


@pytest.mark.shm_alone
def test_killed_agents_are_dropped_and_the_run_completes(tmp_path: Path, ros_env: dict[str, str]) -> None:
    run = tmp_path / 'up'
    shm_before = shm_entries()
    proc = up('--maps', '12', '--seed', '0', '--duration', '20', '--agents-per-process', '1', '--out', str(run),
              env=ros_env)
    seen, rest = kill_during(proc, str(run), '3,7', 't =   2.0 s')
    assert proc.returncode == 0, seen + rest
    assert shm_entries() - shm_before == set(), 'SIGKILLed agents left shared-memory files (segments or ports)'
    assert dropped_ids(seen) == [3, 7], seen
    m = read_csv(run / 'metrics.csv')
    assert m['t'][-1] == 20.0, 'the run completes'
    assert m['alive'][0] == 12 and m['alive'][-1] == 10
    t = read_csv(run / 'trajectory.csv')
    last = set(t['id'][t['step'] == t['step'].max()].astype(int).tolist())
    assert last == set(range(12)) - {3, 7}


def test_kill_of_one_packed_map_ends_its_node_alone(tmp_path: Path, ros_env: dict[str, str]) -> None:
    """A MAP packed with four others is killed alone: its node ends inside the living process, world_sim drops
    exactly it, and the run goes on with one MAP fewer; its four process mates fly to the end. Then
    --whole-processes SIGKILLs a whole process, and what kill prints is what world_sim drops."""
    run = tmp_path / 'up'
    proc = up('--maps', '10', '--seed', '0', '--duration', '150', '--agents-per-process', '5', '--out', str(run),
              env=ros_env)
    try:
        wait_for_line(proc, 't =   2.0 s', 120)
        pids = json.loads((run / 'pids.json').read_text())
        killed = cli('kill', '--run', str(run), '--ids', '3')
        assert killed.returncode == 0 and 'killed MAPs [3]' in killed.stdout, killed.stdout + killed.stderr
        assert 'SIGKILLed' not in killed.stdout, f'no process was SIGKILLed: {killed.stdout}'
        seen = ''.join(wait_for_line(proc, '(killed)', 60))
        assert dropped_ids(seen) == [3], seen
        assert not dead(pids['3']), 'the process of MAP 3 lives on for its other MAPs'
        again = cli('kill', '--run', str(run), '--ids', '3')
        assert again.returncode == 2 and 'MAP 3 is not alive' in again.stderr, again.stderr
        whole = cli('kill', '--run', str(run), '--ids', '7', '--whole-processes')
        assert whole.returncode == 0 and 'killed MAPs [5, 6, 7, 8, 9] (process ' in whole.stdout
        assert 'SIGKILLed with every MAP it held' in whole.stdout, whole.stdout + whole.stderr
        more = ''.join(wait_for_line(proc, '(killed)', 60))
        if len(dropped_ids(more)) < 5:
            more += ''.join(wait_for_line(proc, '(killed)', 60))
        rest, _ = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, seen + rest
    assert dropped_ids(more) == [5, 6, 7, 8, 9], more
    m = read_csv(run / 'metrics.csv')
    assert m['alive'][0] == 10 and m['alive'][-1] == 4 and m['t'][-1] == 150.0
    alive = m['alive'].astype(int)
    assert np.all(np.diff(alive) <= 0) and 9 in alive, 'one fewer after the first kill, then the process of five'
    # (the five of a SIGKILLed process are dropped as each is waited for: those that had answered, a step later)
    t = read_csv(run / 'trajectory.csv')
    last = set(t['id'][t['step'] == t['step'].max()].astype(int).tolist())
    assert last == {0, 1, 2, 4}, 'the killed MAP\'s process mates fly to the end'
    after = cli('kill', '--run', str(run), '--ids', '5')
    assert after.returncode == 2 and 'has ended' in after.stderr, after.stdout + after.stderr


@pytest.mark.shm_alone
def test_a_live_run_seen_by_echo_and_topics_then_a_kill_and_ctrl_c(tmp_path: Path, ros_env: dict[str, str]) -> None:
    """One live run read three ways, as a user would in one sitting: echo and topics show it; echo on a MAP just
    killed ends at once and says so; Ctrl-C then ends every process and keeps the records.

    The killed MAP's stale endpoint still counts as a publisher and no message comes: echo says at once that the
    MAP was killed, and when world_sim dropped it (from the failure events world_sim keeps). echo starts once
    world_sim has said that it dropped the MAP: started at once after the kill, echo may find no drop yet to tell
    of (a fresh-clone run on two busy cores once printed the line without the drop time)."""
    import yaml
    run = tmp_path / 'up'
    shm_before = shm_entries()
    # 1800 s: eight MAPs in lockstep fly about 15 s a second here, and the run must outlast what is asked of it.
    proc = up('--maps', '8', '--seed', '0', '--duration', '1800', '--out', str(run), env=ros_env)
    try:
        wait_for_line(proc, 't =   1.0 s', 120)
        echoed = cli('echo', '/metrics', '--once', '--run', str(run), timeout=60)
        listed = cli('topics', '--run', str(run), timeout=60)
        # A topic the run does not have is one line and exit 2 at once, not a wait for its timeout.
        for topic in ('/no_such_topic', '/map_99/state'):
            t0 = time.monotonic()
            absent = cli('echo', topic, '--run', str(run), '--timeout', '60', timeout=60)
            assert absent.returncode == 2 and 'is not a topic of the run' in absent.stderr, absent.stderr
            assert len(absent.stderr.strip().splitlines()) == 1 and time.monotonic() - t0 < 30
        # `kill PID` ends an echo as Ctrl-C does: quietly once it prints, "interrupted" (130) while it waits.
        for topic, code in (('/metrics', 0), ('/events/finished', 130)):  # the latter comes only at the end
            streaming = subprocess.Popen([sys.executable, '-m', 'uav_flock_tools.cli', 'echo', topic, '--run',
                                          str(run), '--timeout', '100'], stdout=subprocess.PIPE,
                                         stderr=subprocess.PIPE, text=True)
            if code == 0:
                wait_for_line(streaming, '---', 60)
            else:
                time.sleep(3.0)
            streaming.terminate()
            _, said = streaming.communicate(timeout=30)
            assert streaming.returncode == code and 'Traceback' not in said, said
        # A reader that leaves (`| head -3`) ends the echo quietly, as `ros2 topic echo | head` does.
        piped = subprocess.run(['bash', '-c', f'set -o pipefail; {shlex.quote(sys.executable)} -m uav_flock_tools.cli '
                                f'echo /metrics --run {shlex.quote(str(run))} | head -3'],
                               capture_output=True, text=True, timeout=60)
        assert piped.returncode == 0 and piped.stderr == '', piped.stderr
        assert len(piped.stdout.splitlines()) == 3, piped.stdout
        killed = cli('kill', '--run', str(run), '--ids', '3')
        assert killed.returncode == 0, killed.stdout + killed.stderr
        wait_for_line(proc, 'dropped MAPs [3] (killed)', 60)
        gone = cli('echo', '/map_3/state', '--once', '--timeout', '5', '--run', str(run), timeout=120)  # hung before
        pids = list(json.loads((run / 'pids.json').read_text()).values())
        proc.send_signal(signal.SIGINT)
        t0 = time.monotonic()
        while not all(dead(p) for p in pids) and time.monotonic() - t0 < 10:
            time.sleep(0.05)
        gone_after = time.monotonic() - t0
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert echoed.returncode == 0, echoed.stderr
    msg = yaml.safe_load(echoed.stdout.split('---')[0])
    assert list(msg) == ['header', 'step', 't', 'coverage_ratio', 'fiedler', 'alive', 'components', 'mode0',
                         'mode1', 'mode2', 'links', 'vehicle'] and msg['alive'] == 8 and msg['links'] == [], msg
    assert '/map_3/state [uav_flock_msgs/msg/AgentState]' in listed.stdout
    assert '/metrics [uav_flock_msgs/msg/Metrics]' in listed.stdout
    assert gone.returncode == 2 and len(gone.stderr.strip().splitlines()) == 1, gone.stdout + gone.stderr
    assert 'MAP 3 of this run was killed' in gone.stderr and 'dropped it at t =' in gone.stderr, gone.stderr
    # Ctrl-C: no orphan, and the records end where the run was stopped, with the MAPs the world stopped alive.
    assert all(dead(p) for p in pids), 'no orphan agent processes'
    assert gone_after <= 5.0, f'children ended {gone_after:.1f} s after Ctrl-C (limit 5 s)'
    assert 'interrupted' in out
    m = read_csv(run / 'metrics.csv')
    # The agents stopped with the world are not failures: the records end where the run was stopped, every MAP
    # but the killed one alive, not at t = 1800 s after a run on without them.
    assert 1.0 <= m['t'][-1] < 1800 and m['alive'][-1] == 7, (m['t'][-1], m['alive'][-1])
    logs = {p.name: p.read_text() for p in (run / 'logs').glob('*.log')}
    noisy = [name for name, text in logs.items() if 'FATAL' in text or 'Traceback' in text]
    assert not noisy, f'an error logged while stopping: {noisy}\n' + '\n'.join(logs[n] for n in noisy)
    assert shm_entries() - shm_before == set(), 'shared-memory debris left in /dev/shm'
    # Once the run has ended, its topics are gone: both say so at once rather than wait and list nothing.
    for args in (('echo', '/metrics'), ('topics',)):
        after = cli(*args, '--run', str(run), timeout=60)
        assert after.returncode == 2 and 'has ended' in after.stderr, after.stderr


def run_processes(run: Path) -> dict[str, list[int]]:
    """The living processes of a run, found by their command lines: world_sim, recorder, discovery server."""
    info = json.loads((run / 'run.json').read_text())
    port = info['discovery_server'].rsplit(':', 1)[1]
    found: dict[str, list[int]] = {'world_sim': [], 'recorder': [], 'discovery server': []}
    for proc in Path('/proc').iterdir():
        if not proc.name.isdigit() or dead(int(proc.name)):
            continue
        try:
            argv = (proc / 'cmdline').read_bytes().decode(errors='replace').split('\0')
        except OSError:
            continue
        line = ' '.join(argv)
        if 'world_sim_node' in line and f'out:={run}' in line:
            found['world_sim'].append(int(proc.name))
        elif 'uav_flock_recorder' in line and str(run) in line:
            found['recorder'].append(int(proc.name))
        elif argv[0].endswith('fast-discovery-server') and port in argv:
            found['discovery server'].append(int(proc.name))
    return found


def test_a_sigkilled_up_takes_its_whole_run_with_it(tmp_path: Path, ros_env: dict[str, str]) -> None:
    """`up` cannot stop what it started when it is SIGKILLed: the kernel tells its children, and they end."""
    run = tmp_path / 'up'
    proc = up('--maps', '4', '--duration', '600', '--discovery', 'server', '--record', '--out', str(run),
              env=ros_env)
    try:
        wait_for_line(proc, 't =   1.0 s', 120)  # a recorded run with a discovery server gets under way
        children = run_processes(run)
        assert all(len(pids) == 1 for pids in children.values()), children
        agents = list(json.loads((run / 'pids.json').read_text()).values())
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        everyone = agents + [pid for pids in children.values() for pid in pids]
        t0 = time.monotonic()
        while not all(dead(p) for p in everyone) and time.monotonic() - t0 < 10:
            time.sleep(0.05)
        left = {name: [p for p in pids if not dead(p)] for name, pids in {**children, 'agents': agents}.items()}
        assert not any(left.values()), f'outlived the SIGKILLed up: {left}'
        with claim_domain(json.loads((run / 'run.json').read_text())['domain_id']):
            pass  # the domain is free again, and nothing of the dead run is left in it
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.shm_alone
def test_ctrl_c_twice_during_start_up_still_ends_cleanly(tmp_path: Path, ros_env: dict[str, str]) -> None:
    """An impatient user: Ctrl-C while the MAPs are still discovering each other, and again while `up` stops them."""
    run = tmp_path / 'up'
    shm_before = shm_entries()
    proc = up('--maps', '12', '--seed', '0', '--duration', '600', '--out', str(run), env=ros_env)
    wait_for_line(proc, 'run folder', 120)
    time.sleep(1.5)  # agents forked and starting
    proc.send_signal(signal.SIGINT)
    time.sleep(0.3)
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=60)
    assert 'uav-flock up: interrupted; every process ended' in out and 'Traceback' not in out, out
    pids = list(json.loads((run / 'pids.json').read_text()).values()) if (run / 'pids.json').exists() else []
    assert all(dead(pid) for pid in pids), 'agent processes outlived up'
    assert shm_entries() - shm_before == set(), 'shared-memory debris left in /dev/shm'


def test_rogue_state_messages_change_nothing(tmp_path: Path, ros_env: dict[str, str]) -> None:
    """NaN, a wrong sender id and stale steps on /map_3/state from another process: every agent ignores them.

    60 s of simulated time (a few seconds of wall time): in a run of 20 s the rogue's discovery of the agents'
    readers, in another process, did not always complete before the run ended."""
    args = ('--maps', '10', '--seed', '2', '--duration', '60')
    rogue = helper('rogue', '3', env=ros_env)
    try:
        run = cli('up', *args, '--domain-id', ros_env['ROS_DOMAIN_ID'], '--out', str(tmp_path / 'up'), env=ros_env)
    finally:
        rogue.terminate()
        said, _ = rogue.communicate(timeout=30)
    assert run.returncode == 0, run.stdout + run.stderr
    published, readers, _ = (int(v) for v in said.split()[1::2])
    assert published > 30 and readers > 0, f'the rogue must reach the neighbours of MAP 3: {said}'
    assert cli('sim', *args, '--out', str(tmp_path / 'sim')).returncode == 0
    assert (tmp_path / 'up' / 'trajectory.csv').read_bytes() == (tmp_path / 'sim' / 'trajectory.csv').read_bytes()
    logs = ''.join(p.read_text() for p in (tmp_path / 'up' / 'logs').glob('agents_*.log'))
    assert 'rejected a message from /map_3/state' in logs


def test_agents_listen_only_to_maps_in_radio_range(tmp_path: Path, ros_env: dict[str, str]) -> None:
    """Sampled from the live ROS graph: no MAP subscribes to a MAP beyond r + hysteresis. One process a MAP,
    and the run equals the batch simulator's."""
    r, hysteresis, dt = 24.0, 2.0, 0.1
    sampler = helper('graph_sampler', '16', env=ros_env)
    try:
        # One process per MAP, 24 s: a packed run of 16 MAPs is over in a few seconds, and with both cores busy
        # one of 12 s ended before the sampler's discovery of the world's /metrics had completed.
        run = cli('up', '--maps', '16', '--seed', '5', '--duration', '24', '--agents-per-process', '1',
                  '--domain-id', ros_env['ROS_DOMAIN_ID'],
                  '--out', str(tmp_path), env=ros_env)
    finally:
        sampler.terminate()
        said, _ = sampler.communicate(timeout=30)
    assert run.returncode == 0, run.stdout + run.stderr
    # The run is the batch simulator's, to the bit, with a stranger listening; every agent process is gone after it.
    batch = cli('sim', '--maps', '16', '--seed', '5', '--duration', '24', '--out', str(tmp_path / 'sim'))
    assert batch.returncode == 0, batch.stderr
    for name in ('trajectory.csv', 'metrics.csv'):
        assert (tmp_path / name).read_bytes() == (tmp_path / 'sim' / name).read_bytes(), name
    pids = json.loads((tmp_path / 'pids.json').read_text()).values()
    assert len(set(pids)) == 16 and all(dead(p) for p in pids), 'every agent process is gone after the run'
    seen = json.loads(said)
    samples = seen['samples']
    assert samples, f'the sampler must hear the run: {seen["metrics"]} /metrics heard, {seen["nodes"]} MAP nodes discovered'
    t = read_csv(tmp_path / 'trajectory.csv')
    pos = {(int(k), int(i)): np.array([x, y, z]) for k, i, x, y, z in zip(t['step'], t['id'], t['x'], t['y'], t['z'])}
    vel = {(int(k), int(i)): np.hypot(vx, vy) for k, i, vx, vy in zip(t['step'], t['id'], t['vx'], t['vy'])}
    last = int(t['step'].max())
    links = far_pairs = 0
    for k, j, subscribers in samples:
        for i in subscribers:
            steps = [s for s in (k - 1, k, k + 1) if 0 <= s <= last]
            gap = min(np.linalg.norm(pos[(s, i)] - pos[(s, j)]) for s in steps)
            slack = 2 * dt * max(vel[(s, i)] + vel[(s, j)] for s in steps)  # the graph is sampled between steps
            assert gap <= r + hysteresis + slack, f'MAP {i} listens to MAP {j} at {gap:.1f} m (step {k})'
            links += 1
        far_pairs += sum(np.linalg.norm(pos[(k, i)] - pos[(k, j)]) > r + hysteresis + 10
                         for i in range(16) if i != j and (k, i) in pos and (k, j) in pos)
    assert links > 50, f'the sampler saw too few subscriptions ({links}) to judge'
    assert far_pairs > 50, 'the run must have MAPs far apart, or the check proves nothing'


def test_topics_where_no_run_is_says_where_to_look(ros_env: dict[str, str]) -> None:
    """A domain with no run lists only the two topics every node has, and says how to name a run."""
    with claim_domain(None) as domain:
        listed = cli('topics', '--domain-id', str(domain), timeout=120)
    assert listed.returncode == 0, listed.stderr
    assert set(listed.stdout.split()) <= {'/parameter_events', '/rosout', '[rcl_interfaces/msg/ParameterEvent]',
                                          '[rcl_interfaces/msg/Log]'}, listed.stdout
    assert f'ROS_DOMAIN_ID={domain}: no run there' in listed.stderr and '--run RUN' in listed.stderr, listed.stderr
