"""Bags of real runs: what they hold, asserted from the bag alone, and the golden bag replayed."""
from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.bags import assert_nothing_lost
from helpers.runs import cli, dead, ended, up, wait_for_line
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from uav_flock_tools import bag
from world_sim.core.records import read_csv

GOLDEN = Path(__file__).resolve().parents[1] / 'golden'
SCENARIO = str(GOLDEN / 'scenario.yaml')  # 7 MAPs, 10 s: every mode within the run
MODES_ALLOWED = {(0, 0), (0, 1), (0, 2), (1, 1), (2, 2)}  # Algorithm 2: M1 and M2 are kept once reached


@pytest.fixture(scope='module')
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A recorded run with a scheduled failure of 2 of 7 MAPs at t = 6 s."""
    run = tmp_path_factory.mktemp('bags') / 'run'
    done = cli('up', '--scenario', SCENARIO, '--fail-at', '6', '--fail-fraction', '0.3', '--record', '--out', str(run))
    assert done.returncode == 0, done.stdout + done.stderr
    return run


def test_bag_is_rosbag2_mcap_with_our_schemas_and_jazzy_hashes(recorded: Path) -> None:
    folder = recorded / 'bag'
    info = yaml.safe_load((folder / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['storage_identifier'] == 'mcap' and info['relative_file_paths'] == ['bag.mcap']
    listed = {t['topic_metadata']['name']: t for t in info['topics_with_message_count']}
    from ament_index_python.packages import get_package_share_directory
    share = Path(get_package_share_directory('uav_flock_msgs')) / 'msg'
    for topic, kind in (('/map_0/state', 'AgentState'), ('/metrics', 'Metrics'), ('/users', 'Users')):
        meta = listed[topic]['topic_metadata']
        hashes = json.loads((share / f'{kind}.json').read_text())['type_hashes']
        rosidl = next(h['hash_string'] for h in hashes if h['type_name'] == f'uav_flock_msgs/msg/{kind}')
        assert meta['type_description_hash'] == rosidl, f'{kind}: the hash rosidl generated for Jazzy'
        assert meta['offered_qos_profiles'][0]['reliability'] == 'reliable'

    with open(folder / 'bag.mcap', 'rb') as f:  # the mcap library alone, no rosbags
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        schemas = {s.name: s for s in summary.schemas.values()}
        state = schemas['uav_flock_msgs/msg/AgentState']
        assert state.encoding == 'ros2msg'
        text = state.data.decode()
        for line in ('uint32 user_count', 'uint8 MODE_CONNECT=1', 'MSG: geometry_msgs/Point'):
            assert line in text
        counts = {summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()}
    for topic, entry in listed.items():
        assert counts.get(topic, 0) == entry['message_count'], topic
    with AnyReader([folder]) as r:
        assert {c.topic: c.msgcount for c in r.connections} == {t: e['message_count'] for t, e in listed.items()}


def test_every_published_message_is_in_the_bag(recorded: Path) -> None:
    b = assert_nothing_lost(recorded)
    assert b.counts['/users'] == b.counts['/clusters'] == 1
    assert b.counts['/metrics'] == b.counts['/association'] == 101
    assert [len(ids) for _, ids, _ in b.failures] == [2], 'one scheduled failure of 2 MAPs'


def test_the_maps_hear_of_the_end_only_once_the_recorder_holds_their_last_commands(recorded: Path) -> None:
    """A MAP's writer goes when it hears /events/finished: heard first, it could take its last command with it."""
    with AnyReader([recorded / 'bag']) as r:
        finished = [t for c, t, _ in r.messages(connections=[c for c in r.connections if c.topic == '/events/finished'])]
        commands = [t for c, t, _ in r.messages(connections=[c for c in r.connections if c.topic.endswith('/cmd')])]
    assert len(finished) == 1 and commands
    assert max(commands) < finished[0], 'the recorder wrote a command after the run was announced finished'


def test_coverage_and_fiedler_recomputed_from_raw_positions_equal_the_recorded_ones(recorded: Path) -> None:
    b = bag.load(recorded / 'bag')
    again = bag.recompute(b, b.scenario['association'])
    assert np.array_equal(again[:, 0], b.metrics[:, 0])
    assert np.max(np.abs(again[:, 1] - b.metrics[:, 2])) <= 1e-12
    assert np.max(np.abs(again[:, 2] - b.metrics[:, 3])) <= 1e-9


def test_run_trends_modes_and_numbers_from_the_bag_alone(recorded: Path) -> None:
    b = bag.load(recorded / 'bag')
    m = b.metrics
    assert m[-1, 2] > m[0, 2] + 0.5, 'coverage grows as the MAPs reach the clusters'
    assert np.all((m[:, 3] > 0) == (m[:, 5] == 1)), 'λ2 > 0 exactly when the graph is one component'
    assert np.all(np.isfinite(m)) and np.all(np.isfinite(b.trajectory)), 'no NaN anywhere'
    t = b.trajectory
    seen = set()
    for i in np.unique(t[:, 2]):
        modes = t[t[:, 2] == i][:, 9].astype(int)
        pairs = set(zip(modes[:-1].tolist(), modes[1:].tolist()))
        assert pairs <= MODES_ALLOWED, f'MAP {int(i)}: transitions {sorted(pairs - MODES_ALLOWED)}'
        seen |= set(modes.tolist())
    assert seen == {0, 1, 2}, 'the run goes through every mode'
    for step, ids, _ in b.failures:
        before, at = m[m[:, 0] == step - 1][0], m[m[:, 0] == step][0]
        assert before[4] - at[4] == len(ids), 'alive drops by exactly the failed MAPs'
        after = m[m[:, 0] >= step]
        assert after[-1, 2] > after[:, 2].min(), 'coverage recovers after the failure'


@pytest.mark.parametrize('per_process, said, unsaid', [('1', 'SIGKILLed with every MAP', 'ended inside'),
                                                       ('5', 'their nodes ended inside process', 'SIGKILLed')])
def test_killed_agents_leave_a_complete_bag(tmp_path: Path, ros_env: dict[str, str], per_process: str,
                                            said: str, unsaid: str) -> None:
    """Whole processes SIGKILLed (one MAP each), or packed MAPs' nodes ended inside living processes."""
    run = tmp_path / 'up'
    # 10 MAPs step 80-150 times a second here, the kill lands 1-2 s after t = 2 s: 80 s outlasts it three times over.
    proc = up('--scenario', SCENARIO, '--maps', '10', '--duration', '80', '--record', '--agents-per-process',
              per_process, '--out', str(run), env=ros_env)
    try:
        wait_for_line(proc, 't =   2.0 s', 120)
        killed = cli('kill', '--run', str(run), '--fraction', '0.3')
        assert killed.returncode == 0 and said in killed.stdout, killed.stdout + killed.stderr
        assert unsaid not in killed.stdout, f'kill tells of what it did not do: {killed.stdout}'
        assert proc.wait(timeout=300) == 0
    finally:
        proc.kill()
    b = assert_nothing_lost(run)
    dropped = sorted(i for _, ids, cause in b.failures if cause == 'killed' for i in ids)
    assert len(dropped) == 3 and int(b.metrics[-1, 4]) == 7


def test_ctrl_c_leaves_a_finalised_readable_bag(tmp_path: Path, ros_env: dict[str, str]) -> None:
    run = tmp_path / 'up'
    proc = up('--scenario', SCENARIO, '--duration', '60', '--fail-at', '50', '--fail-fraction', '0.2', '--record',
              '--out', str(run), env=ros_env)
    try:
        wait_for_line(proc, 't =   3.0 s', 120)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 130
    finally:
        proc.kill()
    assert (run / 'bag' / 'metadata.yaml').exists(), 'metadata.yaml is written on Ctrl-C'
    b = assert_nothing_lost(run)
    assert 30 <= len(b.metrics) < 601
    # Its report says the run was cut short, and that the failure it was to have never came.
    reported = cli('report', str(run))
    assert reported.returncode == 0, reported.stderr
    assert 'INTERRUPTED: the run was to last 60 s' in reported.stdout, reported.stdout
    assert '20 % of the MAPs were to fail at t = 50 s, after the run was cut short' in reported.stdout, reported.stdout


def test_report_plots_and_summarises_a_bag(tmp_path: Path) -> None:
    done = cli('report', str(GOLDEN / 'bag'), '--out', str(tmp_path / 'report'))
    assert done.returncode == 0, done.stderr
    for name in ('coverage.png', 'fiedler.png', 'modes.png', 'formation.png', 'formation.gif', 'summary.md'):
        assert (tmp_path / 'report' / name).stat().st_size > 1000 or name == 'summary.md', name
    [(_, ids, _)] = bag.load(GOLDEN / 'bag').failures
    assert 'final coverage R_c' in done.stdout and f'MAP {ids[0]} at t = 6.0 s (scheduled)' in done.stdout
    again = cli('report', str(GOLDEN / 'bag'), '--out', str(tmp_path / 'report'))
    assert again.returncode == 2 and 'holds a report already' in again.stderr and again.stderr.count('\n') == 1, \
        again.stderr
    assert cli('report', str(GOLDEN / 'bag'), '--out', str(tmp_path / 'report'), '--replace').returncode == 0


def test_report_writes_scene_mcap_in_foxglove_schemas_with_the_recorded_positions(tmp_path: Path) -> None:
    """scene.mcap opens in Foxglove or Lichtblick: a 3-D scene, metrics to plot and a log, in Foxglove's own
    schemas; read back with the mcap reader alone, its MAP spheres stand where the bag says the MAPs were."""
    from mcap_protobuf.decoder import DecoderFactory

    assert cli('report', str(GOLDEN / 'bag'), '--out', str(tmp_path / 'report')).returncode == 0
    run = bag.load(GOLDEN / 'bag')
    with open(tmp_path / 'report' / 'scene.mcap', 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None
        found = {c.topic: (c.message_encoding, summary.schemas[c.schema_id].name) for c in summary.channels.values()}
        assert found == {'/scene': ('protobuf', 'foxglove.SceneUpdate'), '/metrics': ('json', 'uav_flock.Metrics'),
                         '/log': ('protobuf', 'foxglove.Log')}, found
        scenes = {m.log_time: d for _, c, m, d in reader.iter_decoded_messages(topics=['/scene'])}
        f.seek(0)
        figures = [json.loads(m.data) for _, c, m in make_reader(f).iter_messages(topics=['/metrics'])]
        f.seek(0)
        logs = [d.message for _, c, m, d in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
            topics=['/log'])]
    steps = np.unique(run.trajectory[:, 0]).astype(int)
    assert len(scenes) == len(steps) and len(figures) == len(run.metrics)
    [(fail_step, ids, _)] = run.failures
    assert logs == [f'MAP {ids[0]} lost']
    after = scenes[int(round(run.trajectory[run.trajectory[:, 0] == fail_step][0, 1] * 1e9))]
    assert [d.id for d in after.deletions] == [f'map_{ids[0]}'], 'the lost MAP leaves the scene'
    for k in (int(steps[0]), fail_step, int(steps[-1])):
        rows = run.trajectory[run.trajectory[:, 0] == k]
        spheres = {e.id: e.spheres[0].pose.position for e in scenes[int(round(rows[0, 1] * 1e9))].entities
                   if e.id.startswith('map_')}
        assert set(spheres) == {f'map_{int(i)}' for i in rows[:, 2]}, 'one sphere per MAP flying at that step'
        for row in rows:
            at = spheres[f'map_{int(row[2])}']
            assert (at.x, at.y, at.z) == (row[3], row[4], row[5])
    assert [f['coverage_ratio'] for f in figures] == run.metrics[:, 2].tolist()


def test_bag_tools_take_the_run_folder_or_a_file_of_the_bag(tmp_path: Path) -> None:
    """Users name whatever they have at hand: the run folder `up` printed, or the bag's storage file."""
    shutil.copytree(GOLDEN / 'bag', tmp_path / 'run' / 'bag')
    done = cli('report', str(tmp_path / 'run'))
    assert done.returncode == 0, done.stderr
    assert (tmp_path / 'run' / 'report' / 'summary.md').exists(), 'the report goes next to the bag, as for RUN/bag'
    storage = next((tmp_path / 'run' / 'bag').glob('*.mcap'))
    assert cli('report', str(storage), '--out', str(tmp_path / 'r2')).stdout == done.stdout.replace(
        str(tmp_path / 'run' / 'report'), str(tmp_path / 'r2'))
    replayed = cli('replay', str(tmp_path / 'run'), '--agent', '2')
    assert replayed.returncode == 0 and 'commands compared' in replayed.stdout, replayed.stdout + replayed.stderr


def test_report_on_a_bag_without_steps_says_so(tmp_path: Path) -> None:
    """The bag of a run interrupted before its first step: our fixed topics, no step. Not 'not a run'."""
    early = tmp_path / 'early'
    with AnyReader([GOLDEN / 'bag']) as r:
        writer = Writer(early, version=8, storage_plugin=StoragePlugin.MCAP)
        writer.open()
        fixed = [c for c in r.connections if c.topic in ('/clusters', '/users')]
        conns = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=r.typestore) for c in fixed}
        for c, t, raw in r.messages(connections=fixed):
            writer.write(conns[c.id], t, raw)
        writer.close()
    done = cli('report', str(early), '--out', str(tmp_path / 'r'))
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert 'the bag holds no steps' in done.stderr and 'not a uav-flock run' not in done.stderr, done.stderr
    replayed = cli('replay', str(early), '--agent', '3')  # the same words, not "MAP 3 is not in this bag"
    assert replayed.returncode == 2 and 'the bag holds no steps' in replayed.stderr, replayed.stderr


def test_report_reads_a_bag_without_our_metadata(tmp_path: Path) -> None:
    """A bag as another recorder writes it: sqlite3 storage, no custom_data, extra topics."""
    foreign = tmp_path / 'foreign'
    with AnyReader([GOLDEN / 'bag']) as r:
        writer = Writer(foreign, version=8, storage_plugin=StoragePlugin.SQLITE3)
        writer.open()
        conns = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=r.typestore) for c in r.connections}
        for c, t, raw in r.messages():
            writer.write(conns[c.id], t, raw)
        writer.close()
    ours = cli('report', str(GOLDEN / 'bag'), '--out', str(tmp_path / 'a'))
    theirs = cli('report', str(foreign), '--out', str(tmp_path / 'b'))
    assert theirs.returncode == 0, theirs.stderr
    assert theirs.stdout.splitlines()[:-1] == ours.stdout.splitlines()[:-1], 'the same summary table'


def test_golden_bag_replays_exactly_for_every_map() -> None:
    """Fails on any change of agent behaviour; regenerate on purpose with tests/golden/regenerate.py."""
    maps = bag.load(GOLDEN / 'bag').heard['sensing'][0]
    for i in sorted(maps):
        done = cli('replay', str(GOLDEN / 'bag'), '--agent', str(i))
        assert done.returncode == 0, f'MAP {i} behaves differently from the golden bag:\n{done.stdout}{done.stderr}'
        assert 'commands compared' in done.stdout


def test_replay_with_a_parameter_changed_is_an_experiment(tmp_path: Path) -> None:
    """--set is asked for on purpose: exit 0, how the commands differ, and |Δu| over time as a plot."""
    for value in ('c1=0.35', 'c1=1'):  # `c1=1` reads as an integer: the agent's double parameter still takes it
        plot = tmp_path / f'{value}.png'
        done = cli('replay', str(GOLDEN / 'bag'), '--agent', '2', '--set', value, '--plot', str(plot))
        assert done.returncode == 0, done.stdout + done.stderr
        said = done.stdout
        assert f'MAP 2 with {value}' in said and '|Δu|: max' in said and 'first difference at step' in said, said
        steps = int(re.search(r'(\d+) commands compared', said)[1])
        differ = int(re.search(r'(\d+) of \d+ steps differ', said)[1])
        assert steps > 0 and 0 < differ <= steps, said
        assert plot.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n' and str(plot) in said
    # Without --plot, a bag that is in no run folder (the golden bag, tracked by git) is left as it was.
    before = sorted(p.name for p in GOLDEN.iterdir())
    done = subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'replay', str(GOLDEN / 'bag'), '--agent', '2',
                           '--set', 'c1=0.35'], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert sorted(p.name for p in GOLDEN.iterdir()) == before, 'replay wrote into tests/golden'
    assert len(list((tmp_path / 'runs').glob('replay-*/replay_map2.png'))) == 1, done.stdout
    # In a run folder, a second experiment is drawn beside the first, never over it.
    import shutil
    run = tmp_path / 'run'
    shutil.copytree(GOLDEN / 'bag', run / 'bag')
    (run / 'run.json').write_text('{}')
    for value in ('c1=0.35', 'c1=0.4'):
        done = cli('replay', str(run / 'bag'), '--agent', '2', '--set', value)
        assert done.returncode == 0 and 'Warning' not in done.stderr, done.stdout + done.stderr
    assert sorted(p.name for p in run.glob('replay_map2*.png')) == ['replay_map2-2.png', 'replay_map2.png']


def test_a_replay_without_set_that_differs_fails() -> None:
    """Without --set a difference is a finding about the code: exit 1 (the CLI's `0 if ok else 1`)."""
    from uav_flock_tools.replay import Outcome
    differs = Outcome(agent=2, steps=10, mismatches=['step 3: |Δu| = 0.1'])
    assert not differs.ok and 'behaviour differs from the recording' in differs.describe()
    assert Outcome(agent=2, steps=10, mismatches=['step 3'], changed={'c1': 0.4}).ok


def children(pid: int) -> list[int]:
    return [int(c) for t in Path(f'/proc/{pid}/task').iterdir() for c in (t / 'children').read_text().split()]


def test_kill_pid_on_replay_stops_its_agent(tmp_path: Path) -> None:
    """SIGTERM, as `kill PID` sends: the replay's own agent process must not outlive it."""
    replaying = subprocess.Popen([sys.executable, '-m', 'uav_flock_tools.cli', 'replay', str(GOLDEN / 'bag'),
                                  '--agent', '3'], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not (agents := children(replaying.pid)) and replaying.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert agents, 'replay started no agent process'
    replaying.terminate()
    _, said = replaying.communicate(timeout=30)
    assert replaying.returncode == 130 and said.strip() == 'uav-flock: interrupted', said
    assert all(dead(pid) for pid in agents), 'the agent outlived the replay'


def test_a_recorder_that_dies_is_reported_and_the_run_goes_on(tmp_path: Path, ros_env: dict[str, str]) -> None:
    """The user asked for a bag and will not get a whole one: the terminal says so, live and at the end."""
    run = tmp_path / 'run'
    proc = up('--maps', '3', '--duration', '30', '--record', '--out', str(run), env=ros_env)
    try:
        seen = ''.join(wait_for_line(proc, 't =   1.0 s', 120))
        recorder = [pid for pid in children(proc.pid)
                    if 'uav_flock_recorder' in Path(f'/proc/{pid}/cmdline').read_text(errors='replace')]
        assert len(recorder) == 1, 'up started one recorder'
        os.kill(recorder[0], signal.SIGKILL)
        rest = ended(proc, 120, run)
    finally:
        if proc.poll() is None:
            proc.kill()
    said = seen + rest
    assert proc.returncode == 1, said
    assert '[ERROR] [world_sim]: the recorder wrote nothing new' in said, 'world_sim\'s error reaches the terminal'
    assert 'recorder ended during the run (killed by SIGKILL' in said and 'is incomplete' in said, said
    assert read_csv(run / 'metrics.csv')['t'][-1] == 30.0, 'the run went on to its end without the recorder'


def test_replay_refuses_a_realtime_bag_in_one_line(tmp_path: Path) -> None:
    """A realtime MAP flies on whatever states came in: its commands cannot be reproduced, and saying
    "behaviour differs" of all of them would be a false alarm."""
    shutil.copytree(GOLDEN / 'bag', tmp_path / 'bag')
    meta = tmp_path / 'bag' / 'metadata.yaml'
    doc = yaml.safe_load(meta.read_text())
    custom = doc['rosbag2_bagfile_information']['custom_data']
    custom[bag.SCENARIO_KEY] = json.dumps({**json.loads(custom[bag.SCENARIO_KEY]), 'sync': 'realtime'})
    meta.write_text(yaml.safe_dump(doc))
    done = cli('replay', str(tmp_path / 'bag'), '--agent', '2')
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stdout + done.stderr
    assert '--sync realtime' in done.stderr and 'lockstep bag' in done.stderr, done.stderr
    assert 'commands compared' not in done.stdout


def test_bag_tools_reject_bad_input_in_one_line(tmp_path: Path) -> None:
    for args in (('report', str(tmp_path / 'missing')), ('report', str(GOLDEN / 'scenario.yaml')),
                 ('report', str(tmp_path)), ('replay', str(tmp_path), '--agent', '3'),  # a folder, no bag in it
                 ('replay', str(GOLDEN / 'bag'), '--agent', '99'),
                 ('report', str(GOLDEN / 'bag'), '--out', str(GOLDEN / 'scenario.yaml'))):
        done = cli(*args)
        assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    # A value the agent would refuse is refused before it starts, in the words of the option typed.
    for value, says in (('r=-1', '--set r: must be positive'), ('zero_users=sometimes', '--set zero_users: must be one of')):
        done = subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'replay', str(GOLDEN / 'bag'), '--agent', '3',
                               '--set', value], cwd=tmp_path, capture_output=True, text=True, timeout=300)
        assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1 and says in done.stderr, done.stderr
        assert not (tmp_path / 'runs').exists(), 'a refused --set wrote a folder for its plot'
    (tmp_path / 'broken').mkdir()
    (tmp_path / 'broken' / 'metadata.yaml').write_text('rosbag2_bagfile_information: [\n')
    done = cli('report', str(tmp_path / 'broken'))  # rosbags' own message spans lines: one line all the same
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    shutil.copytree(GOLDEN / 'bag', tmp_path / 'bag')
    again = cli('up', '--scenario', SCENARIO, '--record', '--out', str(tmp_path))
    assert again.returncode == 2 and 'holds files already' in again.stderr  # a bag is never overwritten


def test_a_run_folder_is_never_shared_by_two_runs(tmp_path: Path) -> None:
    """A second `up` into a run's folder is refused in one line; with --replace the folder is the new run alone."""
    run = tmp_path / 'r'
    first = cli('up', '--maps', '3', '--duration', '2', '--record', '--out', str(run))
    assert first.returncode == 0, first.stdout + first.stderr
    before = {p.name: p.stat().st_mtime_ns for p in run.iterdir()}
    again = cli('up', '--maps', '4', '--duration', '2', '--out', str(run))
    assert again.returncode == 2 and len(again.stderr.strip().splitlines()) == 1, again.stdout + again.stderr
    assert '--replace' in again.stderr
    assert {p.name: p.stat().st_mtime_ns for p in run.iterdir()} == before, 'nothing of the first run was touched'
    replaced = cli('up', '--maps', '4', '--duration', '2', '--replace', '--out', str(run))
    assert replaced.returncode == 0, replaced.stdout + replaced.stderr
    assert not (run / 'bag').exists() and not (run / 'report').exists(), 'the old bag went with the old run'
    assert json.loads((run / 'run.json').read_text())['maps'] == 4
    assert set(read_csv(run / 'trajectory.csv')['id'].astype(int)) == {0, 1, 2, 3}
    stray = tmp_path / 'notes'
    stray.mkdir()
    (stray / 'thesis.tex').write_text('mine')
    refused = cli('sim', '--maps', '3', '--duration', '1', '--replace', '--out', str(stray))
    assert refused.returncode == 2 and 'not a run folder' in refused.stderr and (stray / 'thesis.tex').exists()


def test_rviz_markers_show_maps_by_mode_links_msds_and_centroids(recorded: Path) -> None:
    from world_sim.markers import MODE_RGB
    b = bag.load(recorded / 'bag')
    with AnyReader([recorded / 'bag']) as r:
        frames = [r.deserialize(raw, c.msgtype) for c, _, raw in r.messages([c for c in r.connections
                                                                            if c.topic == '/markers'])]
    assert len(frames) == 21, 'one frame every 5 steps of 101'
    t = read_csv(recorded / 'trajectory.csv')  # the world's record: each MAP's mode after step k's decision
    for n, frame in enumerate(frames):
        k = 5 * n
        by_ns = {m.ns: m for m in frame.markers}
        assert set(by_ns) == {'maps', 'links', 'msds', 'clusters'}
        assert all(m.header.frame_id == 'world' for m in frame.markers)
        at = t['step'] == k
        q = np.column_stack([t['x'][at], t['y'][at], t['z'][at]])
        assert len(by_ns['maps'].points) == len(q) == int(b.metrics[k, 4])
        for p, c, xyz, mode in zip(by_ns['maps'].points, by_ns['maps'].colors, q, t['mode'][at]):
            assert (p.x, p.y) == (xyz[0], xyz[1])
            assert (c.r, c.g, c.b) == pytest.approx(MODE_RGB[int(mode)], abs=1e-6), 'MAP coloured by its mode'
        d = np.linalg.norm(q[:, None] - q[None], axis=-1)
        assert len(by_ns['links'].points) == 2 * int(np.count_nonzero(np.triu(d <= b.r, 1)))
        assert b.users is not None
        assert len(by_ns['msds'].points) == len(by_ns['msds'].colors) == len(b.users.xyz)
        assert len(by_ns['clusters'].points) == len(b.users.centroids) == 3


def test_a_run_under_a_channel_records_and_reports_what_the_maps_heard(tmp_path: Path, ros_env: dict[str, str]) -> None:
    """/metrics carries the channel's figures: the bag holds metrics.csv's every column, the report says and
    plots what the MAPs heard, and a MAP replayed from the bag hears through the same channel."""
    doc = yaml.safe_load((GOLDEN / 'scenario.yaml').read_text())
    doc['links'] = {'delivery': 'alpha', 'loss': 0.3, 'latency': 1}
    (tmp_path / 'lossy.yaml').write_text(yaml.safe_dump(doc))
    done = cli('up', '--scenario', str(tmp_path / 'lossy.yaml'), '--record', '--out', str(tmp_path / 'run'), env=ros_env)
    assert done.returncode == 0, done.stdout + done.stderr
    csv_rows = np.loadtxt(tmp_path / 'run' / 'metrics.csv', delimiter=',', skiprows=1)
    assert csv_rows.shape[1] == 15
    assert np.allclose(bag.load(tmp_path / 'run' / 'bag').metrics, csv_rows, rtol=1e-9, atol=0), 'the bag holds every column'
    assert cli('report', str(tmp_path / 'run' / 'bag'), '--out', str(tmp_path / 'report')).returncode == 0
    text = (tmp_path / 'report' / 'summary.md').read_text()
    assert 'usable graph connected' in text and 'neighbour states heard' in text, text
    assert (tmp_path / 'report' / 'links.png').stat().st_size > 1000
    replayed = cli('replay', str(tmp_path / 'run'), '--agent', '3')
    assert replayed.returncode == 0 and 'commands compared' in replayed.stdout, \
        'a MAP replayed from the bag decides under the same channel: ' + replayed.stdout + replayed.stderr
