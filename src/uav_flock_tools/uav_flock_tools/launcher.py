"""`./uav-flock up`: a run of world_sim, the MAP agents and a recorder as real OS processes, from start to end.

`up` goes through five stages, top-down: plan (its domain, discovery and processes: `domains`), files,
start (`spawn`: children that die with their parent, agents forked from a template), supervise, and stop
(every process ended, `cleanup` of what they left in shared memory), whatever happens on the way."""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

from uav_agent.core.links import describe
from uav_flock_ros.processes import CRASH_DIR, LINKS_LOG_DIR, TEARDOWN_SIGNAL, write_params
from world_sim.core import airframes
from world_sim.core.scenario import Scenario

from . import bag, secure, viewer
from .cleanup import clean_shared_memory
from .domains import DiscoveryServer, DomainClaim, claim_domain, discovery_server_address, ros_env
from .spawn import (GRACE_S, ForkedAgent, describe_exit, dies_with_parent, executable, relay_log,
                    start_agents, stop, write_pid_table)

# rmw_fastrtps finds no more than about 32 participants on one host with LOCALHOST discovery; beyond
# this many processes `up` starts a Fast DDS discovery server for the run (--discovery auto).
LOCALHOST_LIMIT = 30
# Nor beyond this many MAPs: 200 MAPs in 10 processes stalled at step 1 with LOCALHOST discovery (rmw's
# shared memory and 208 KiB UDP buffers) and ran with the server (UDP, 4 MB buffers; docs/benchmarks.md).
LOCALHOST_MAPS_LIMIT = 100
# How long world_sim waits for every MAP, and each MAP for world_sim, at start: Python processes on two
# cores come up at about one per 0.6 s of CPU, so the wait grows with their number.
START_TIMEOUT_MIN_S = 60.0
START_TIMEOUT_PER_PROCESS_S = 1.5
JOIN_TIMEOUT_S = 300.0  # a run that listens for agents of other hosts waits this long for them to appear


@dataclass
class Plan:
    """Everything a run needs decided before anything starts: its domain, discovery, processes and files."""

    scenario_path: Path
    scenario: Scenario
    run: Path
    agents_per_process: int
    record: bool
    sync: str
    rate: float
    claim: DomainClaim
    server_address: Optional[str]
    discovery_range: str
    env: dict[str, str]
    start_timeout: float
    groups: list[list[int]]   # MAP ids per agent process on this host
    remote: list[int]         # MAP ids whose agents join from other hosts (`agents --join`)
    view: Optional[int] = None  # the live view's port (viewer.py), None: no live view
    secure: Optional[secure.HostKeys] = None  # this host's keys: every participant on TCP with TLS (secure.py)

    @property
    def bag_path(self) -> Path:
        return self.run / 'bag'

    @property
    def logs(self) -> Path:
        return self.run / 'logs'

    @property
    def super_env(self) -> dict[str, str]:
        """The recorder's and the live view's: they find their topics in the graph, which only a super-client hears
        of whole when there is a discovery server."""
        return secure.role_env(self.env, self.run, self.secure, 'super_client') if self.secure is not None else \
            {**self.env, 'ROS_SUPER_CLIENT': 'TRUE'} if self.server_address else self.env


def plan(scenario_path: Path, scenario: Scenario, run: Path, agents_per_process: int, domain_id: Optional[int],
         discovery: str, record: bool, sync: str, rate: float, listen: Optional[str] = None,
         agents_here: Optional[int] = None, view: Optional[int] = None, keys: Optional[secure.HostKeys] = None,
         start_timeout: Optional[float] = None) -> Plan:
    """Stage 1: decide the run (and claim its ROS_DOMAIN_ID, held until every process of it has ended).

    With listen (an address of this host that the others reach), the discovery server listens there and
    MAPs agents_here.. are left to agents that join from other hosts. With keys too, every participant of the
    run speaks TCP with TLS, the discovery server included, on the same port (secure.py).
    """
    if record and (run / 'bag').exists():
        raise FileExistsError(f'{run / "bag"} exists already: give a new --out folder')
    here = scenario.maps if agents_here is None else min(agents_here, scenario.maps)
    groups = [list(range(first, min(first + agents_per_process, here))) for first in range(0, here, agents_per_process)]
    processes = len(groups) + 1 + int(record) + int(view is not None)
    use_server = listen is not None or discovery == 'server' or (
        discovery == 'auto' and (processes > LOCALHOST_LIMIT or scenario.maps > LOCALHOST_MAPS_LIMIT))
    claim = claim_domain(domain_id)
    server_address = discovery_server_address(claim.domain, listen or '127.0.0.1') if use_server else None
    discovery_range = 'SUBNET' if discovery == 'subnet' else 'LOCALHOST'
    timeout = start_timeout or max(START_TIMEOUT_MIN_S, START_TIMEOUT_PER_PROCESS_S * processes,
                                   JOIN_TIMEOUT_S if listen is not None else 0.0)  # time to start agents elsewhere
    env = secure.role_env(ros_env(claim.domain, server_address, discovery_range), run, keys, 'client')
    return Plan(scenario_path, scenario, run, agents_per_process, record, sync, rate, claim, server_address,
                discovery_range, env, timeout, groups, list(range(here, scenario.maps)), view, keys)


class Run:
    """Stages 2 to 5 of `up`: write the run's files, start its processes, supervise, stop them all.

    A Ctrl-C (or SIGTERM) while a process is being started waits until that process is in hand, so that
    nothing escapes the stop; at any other time it ends supervision at once."""

    def __init__(self, p: Plan) -> None:
        self.p = p
        self.info: dict[str, object] = {}
        self.agents: list[ForkedAgent] = []
        self.world: Optional[subprocess.Popen] = None
        self.world_log: Optional[threading.Thread] = None
        self.recorder: Optional[subprocess.Popen] = None
        self.viewer: Optional[subprocess.Popen] = None
        self.server: Optional[DiscoveryServer] = None
        self.recorder_gone: Optional[int] = None
        self.interrupted = self.starting = self.stopping = False
        self.began_at = time.time()  # wall clock, as file times are

    # ------------------------------------------------------------------ 2. files
    def write_files(self) -> Path:
        """agent_params.yaml, run.json and logs/; returns the agents' parameter file."""
        p, s = self.p, self.p.scenario
        p.run.mkdir(parents=True, exist_ok=True)
        agent_params = {**bag.run_params(s), 'sync': p.sync, 'world_start_timeout': 2 * p.start_timeout}
        if p.sync == 'realtime' and not s.links.perfect:  # each MAP writes which states the channel lost
            agent_params['links_log'] = str(p.run / LINKS_LOG_DIR)
        params = write_params(p.run / 'agent_params.yaml', {**agent_params, 'crash_dir': str(p.run / CRASH_DIR)})
        self.info = {'domain_id': p.claim.domain, 'discovery_server': p.server_address,
                     'discovery_range': None if p.server_address else p.discovery_range,
                     'secure': secure.for_run(p.secure, p.server_address, p.run) if p.secure is not None else None,
                     'scenario': str(p.scenario_path), 'scenario_flown': 'scenario.yaml', 'maps': s.maps, 'seed': s.seed,
                     'duration': s.duration, 'vehicle': s.vehicle.model, 'agents_per_process': p.agents_per_process,
                     'sync': p.sync, 'rate': p.rate if p.sync == 'realtime' else None,
                     'bag': str(p.bag_path) if p.record else None}
        if p.remote:
            self.info['remote_ids'] = [p.remote[0], p.remote[-1]]
            # What `agents --join` fetches from /run_info: the MAPs it may serve and the agents' parameters.
            (p.run / 'join.json').write_text(json.dumps({'maps': s.maps, 'remote_ids': self.info['remote_ids'],
                                                         'domain_id': p.claim.domain, 'agent_params': agent_params}))
        self.write_info()
        p.logs.mkdir(exist_ok=True)
        maps = f'{s.maps} MAPs, {s.maps - len(p.remote)} of them here,' if p.remote else f'{s.maps} MAPs'
        pace = f'realtime x{p.rate:g}' if p.sync == 'realtime' else 'lockstep'
        found = 'server ' + p.server_address if p.server_address else p.discovery_range
        said = [f'{maps} in {len(p.groups)} process{"es" if len(p.groups) != 1 else ""}, {pace}, '
                f'ROS_DOMAIN_ID={p.claim.domain}, discovery {found}, {s.vehicle.model} vehicle, run folder {p.run}']
        said += [] if s.links.perfect else [f'radio between MAPs: {describe(s.links)}']
        said += [f'vehicle: {s.vehicle.describe()}']
        said += [] if p.secure is None else [secure.banner(p.secure)]
        said += [f'MAPs {p.remote[0]}-{p.remote[-1]} join from other hosts: ./uav-flock agents --join '
                 f'{p.server_address} --ids {p.remote[0]}-{p.remote[-1]}{secure.join_option(p.secure)} '
                 f'(waiting {p.start_timeout:.0f} s)'] if p.remote else []
        print('\n'.join(f'uav-flock up: {line}' for line in said), flush=True)
        return params

    def write_info(self) -> None:
        (self.p.run / 'run.json').write_text(json.dumps(self.info, indent=1))

    # ------------------------------------------------------------------ 3. start
    def on_signal(self, signum: int, frame: object) -> None:
        if self.interrupted or self.stopping:  # a second Ctrl-C, or one while the run is being stopped
            return
        self.interrupted = True
        if not self.starting:  # while a process is started, the interrupt waits until it is in hand
            raise KeyboardInterrupt

    def raise_if_interrupted(self) -> None:
        """Between two starts: act on a Ctrl-C that came while the last one was under way."""
        if self.interrupted:
            raise KeyboardInterrupt

    def start(self, params: Path) -> None:
        """Discovery server, recorder, world (first, so the agents do not starve its start-up), agents."""
        p, s = self.p, self.p.scenario
        self.starting = True
        if p.server_address:
            self.server = DiscoveryServer(p.server_address, p.env, p.logs / 'discovery_server.log',
                                          secure.role_profile(p.run, p.secure, 'server'))
            self.info['discovery_server_pid'] = self.server.proc.pid
        self.raise_if_interrupted()
        if p.record:
            rec_params = write_params(p.run / 'recorder_params.yaml', {
                'out': str(p.bag_path), 'maps': s.maps, 'sync': p.sync, 'params_json': json.dumps(bag.run_params(s)),
                'scenario_json': json.dumps({**bag.scenario_summary(p.scenario_path, s), 'sync': p.sync})})
            self.recorder = subprocess.Popen(
                [executable('uav_flock_tools', 'uav_flock_recorder'), '--ros-args', '--params-file', str(rec_params)],
                env=p.super_env, stdout=open(p.logs / 'recorder.log', 'w'), stderr=subprocess.STDOUT,
                start_new_session=True, preexec_fn=dies_with_parent(signal.SIGINT))
            self.raise_if_interrupted()
        if p.view is not None:
            self.viewer = subprocess.Popen(
                [executable('uav_flock_tools', 'uav_flock_viewer'), '--ros-args', '-p', f'maps:={s.maps}',
                 '-p', f'r:={float(s.flock.r)}', '-p', f'port:={p.view}'],
                env=p.super_env, stdout=open(p.logs / 'viewer.log', 'w'), stderr=subprocess.STDOUT,
                start_new_session=True, preexec_fn=dies_with_parent(signal.SIGINT))
            threading.Thread(target=viewer.announce, daemon=True,
                             args=(self.viewer, p.view, p.logs / 'viewer.log', lambda: self.stopping)).start()
            self.raise_if_interrupted()
        world_args = [executable('world_sim', 'world_sim_node'), '--ros-args',
                      '-p', f'scenario:={p.scenario_path}', '-p', f'maps:={s.maps}',
                      '-p', f'seed:={s.seed}', '-p', f'duration:={float(s.duration)}', '-p', f'out:={p.run}',
                      '-p', f'pid_table:={p.run / "pids.json"}', '-p', f'start_timeout:={p.start_timeout}',
                      '-p', f'sync:={p.sync}', '-p', f'rate:={float(p.rate)}', '-p', f'vehicle:={s.vehicle.model}']
        world_args += ['-p', 'record:=true'] if p.record else []
        world_args += ['-p', f'fail_at:={float(s.fail_at)}', '-p', f'fail_fraction:={float(s.fail_fraction)}'] \
            if s.fail_at is not None else []
        world_args += ['-p', f'run_info:={p.run / "join.json"}'] if p.remote else []
        world_env = {**p.env, **airframes.environment(s.vehicle.model)}  # what its airframe's process needs
        self.world = subprocess.Popen(world_args, env=world_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                      text=True, start_new_session=True, preexec_fn=dies_with_parent(signal.SIGINT))
        self.world_log = relay_log(self.world.stderr, p.logs / 'world.log')  # type: ignore[arg-type]
        self.info['world_pid'] = self.world.pid  # for run_has_ended
        self.write_info()
        self.raise_if_interrupted()
        start_agents(p.groups, params, p.env, p.logs, self.agents, lambda: self.interrupted)
        self.raise_if_interrupted()
        self.starting = False
        write_pid_table(p.run / 'pids.json', {i: a.pid for ids, a in zip(p.groups, self.agents) for i in ids})

    # ------------------------------------------------------------------ 4. supervise
    def supervise(self) -> int:
        """world_sim's progress lines to the terminal until it ends; its exit code."""
        assert self.world is not None and self.world.stdout is not None
        for line in self.world.stdout:
            print(line.rstrip(), flush=True)
        code = self.world.wait()
        if code == -TEARDOWN_SIGNAL:  # a run that ended well, its records written (processes.leave_after)
            print("uav-flock up: world_sim's DDS teardown hung after the run; ended, its records whole", flush=True)
            return 0
        return code

    # ------------------------------------------------------------------ 5. stop
    def stop_all(self) -> None:
        """World and agents together, the world signalled first (SIGINT: it writes its records and takes the
        agents' ends for the stop, not for failures); the recorder once the world has published its last,
        then it drains and closes the bag; the discovery server last."""
        self.stopping = True
        self.recorder_gone = self.recorder.poll() if self.recorder is not None else None  # ends only when told
        stop([self.world] if self.world is not None else [], signal.SIGINT, {signal.SIGTERM: self.agents})
        stop([child for child in (self.recorder, self.viewer) if child is not None], signal.SIGINT)
        if self.server is not None:
            self.server.stop()
        # A SIGKILLed agent cannot remove its files, nor one stopped while its participant was made (at start-up).
        if not self.p.server_address and (self.interrupted or any(a.poll() == -signal.SIGKILL for a in self.agents)):
            clean_shared_memory(self.p.env, since=self.began_at)
        self.p.claim.release()
        if self.world_log is not None:
            self.world_log.join(timeout=GRACE_S)  # its stream ended with world_sim: the file is complete

    def report(self, code: int) -> int:
        """What went wrong, in one line each, and the exit code up ends with."""
        p = self.p
        if self.interrupted:
            print(f'uav-flock up: interrupted; every process ended, records so far in {p.run}', file=sys.stderr)
        if code not in (0, 130):
            log = p.logs / 'world.log'
            tail = log.read_text().strip().splitlines()[-1:] if log.exists() else []
            print(f'uav-flock up: world_sim failed ({describe_exit(code)}){": " + tail[0] if tail else ""}',
                  file=sys.stderr)
        if self.recorder_gone is not None:
            print(f'uav-flock up: the recorder ended during the run ({describe_exit(self.recorder_gone)}, see '
                  f'{p.logs / "recorder.log"}); the bag in {p.bag_path} is incomplete', file=sys.stderr)
            code = code or 1
        return code


def up(scenario_path: Path, scenario: Scenario, run: Path, agents_per_process: int = 1,
       domain_id: Optional[int] = None, discovery: str = 'auto', record: bool = False,
       sync: str = 'lockstep', rate: float = 1.0, listen: Optional[str] = None,
       agents_here: Optional[int] = None, note: Optional[str] = None,
       view: Optional[int] = None, keys: Optional[secure.HostKeys] = None, start_timeout: Optional[float] = None) -> int:
    """Run the scenario distributed, in stages; returns the exit code (the records are in the run folder).
    A note (e.g. too few MAPs for the layout) goes to stderr once the run is planned and its files written."""
    r = Run(plan(scenario_path, scenario, run, agents_per_process, domain_id, discovery, record, sync, rate,
                 listen, agents_here, view, keys, start_timeout))
    old_int, old_term = signal.signal(signal.SIGINT, r.on_signal), signal.signal(signal.SIGTERM, r.on_signal)
    try:
        try:
            params = r.write_files()
            if note:
                print(note, file=sys.stderr, flush=True)
            r.start(params)
            code = r.supervise()
        except KeyboardInterrupt:
            code = 130
        finally:
            r.stop_all()
        # Still under our handler, which ignores a Ctrl-C from the stop on: one that came just after the
        # processes ended must not cut the report short.
        return r.report(code)
    finally:
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGTERM, old_term)
