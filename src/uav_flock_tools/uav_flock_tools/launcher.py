"""Start world_sim and the MAP agents as real OS processes, and end them all, whatever happens.

Every run holds its own ROS_DOMAIN_ID (claim_domain), so runs on one host never hear each other. Fast DDS
is told to use UDP only, with large socket buffers; rmw_fastrtps overrides that with its own transports
(loopback UDP and shared memory) when discovery is LOCALHOST (docs/design.md).
"""
from __future__ import annotations

import ctypes
import fcntl
import json
import multiprocessing
import os
import random
import re
import select
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Callable, Optional, Sequence, Union

from setproctitle import setproctitle

from uav_flock_ros.processes import write_params
from world_sim.core.model import RunResult
from world_sim.core import records
from world_sim.core.scenario import Scenario

GRACE_S = 3.0  # after SIGINT/SIGTERM, how long children get before SIGKILL
# rmw_fastrtps finds no more than about 32 participants on one host with LOCALHOST discovery; beyond
# this many processes `up` starts a Fast DDS discovery server for the run (--discovery auto).
LOCALHOST_LIMIT = 30
# Nor beyond this many MAPs: 200 MAPs in 10 processes stalled at step 1 with LOCALHOST discovery (rmw's
# shared memory and 208 KiB UDP buffers) and ran with the server (UDP, 4 MB buffers; docs/benchmarks.md).
LOCALHOST_MAPS_LIMIT = 100
DISCOVERY_BASE_PORT = 11811
# How long world_sim waits for every MAP, and each MAP for world_sim, at start: Python processes on two
# cores come up at about one per 0.6 s of CPU, so the wait grows with their number.
START_TIMEOUT_MIN_S = 60.0
START_TIMEOUT_PER_PROCESS_S = 1.5
JOIN_TIMEOUT_S = 300.0  # a run that listens for agents of other hosts waits this long for them to appear


def executable(package: str, name: str) -> str:
    """The console script `ros2 run package name` would start."""
    from ament_index_python.packages import get_package_prefix
    return os.path.join(get_package_prefix(package), 'lib', package, name)


# Socket buffers of a run's participants (discovery server or subnet; LOCALHOST discovery keeps rmw's own
# transports). The kernel's default (208 KiB) overflows when a hundred nodes subscribe at once, and
# reliable DDS then spends its time repairing dropped datagrams.
SOCKET_BUFFER_BYTES = 4 * 1024 * 1024


def ros_env(domain_id: int, discovery_server: Optional[str] = None, discovery_range: str = 'LOCALHOST'
            ) -> dict[str, str]:
    """Environment of a run's processes: its own domain, and its discovery server if it has one."""
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(domain_id), FASTDDS_BUILTIN_TRANSPORTS=f'UDPv4?sockets_size={SOCKET_BUFFER_BYTES}',
               PYTHONUNBUFFERED='1')
    if discovery_server:
        env['ROS_DISCOVERY_SERVER'] = discovery_server
        env.pop('ROS_AUTOMATIC_DISCOVERY_RANGE', None)
    else:
        env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = discovery_range
        env.pop('ROS_DISCOVERY_SERVER', None)
    return env


def discovery_server_address(domain_id: int, host: str = '127.0.0.1') -> str:
    """One port per domain, so that runs in different domains each have their own server."""
    return f'{host}:{DISCOVERY_BASE_PORT + domain_id}'


PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def dies_with_parent(signum: int) -> Callable[[], None]:
    """A Popen preexec_fn: the kernel sends the child signum when this process ends (a parent-death signal).

    A run's processes live in sessions of their own, so a SIGKILLed `up` or `replay`, which cannot stop them,
    would leave them running: world_sim to the end of its run and the discovery server for ever, in a
    domain that the dead command no longer claims.
    """
    me = os.getpid()

    def in_child() -> None:
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signum, 0, 0, 0)
        if os.getppid() != me:  # we ended before the request was made
            os.kill(os.getpid(), signum)

    return in_child


def end_with(pid: int, signum: int) -> None:
    """Send signum to this process when process pid ends (a thread waits on its pidfd).

    For a forked agent, whose parent is the template process: that one lives on while any agent holds
    the pipe that multiprocessing keeps it alive by, so a parent-death signal from it would never come.
    """
    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        os.kill(os.getpid(), signum)
        return
    except OSError:  # a kernel without pidfds (before Linux 5.3): the agent still ends when world_sim does
        return

    def wait() -> None:
        select.select([fd], [], [])
        os.kill(os.getpid(), signum)

    threading.Thread(target=wait, name=f'end-with-{pid}', daemon=True).start()


def start_discovery_server(address: str, env: dict[str, str], log: Path) -> subprocess.Popen:
    """The Fast DDS discovery server the wheels ship, on address (host:port), in its own session."""
    host, port = address.rsplit(':', 1)
    with open(log, 'w') as out:
        return subprocess.Popen(['fast-discovery-server', '-i', '0', '-l', host, '-p', port],
                                env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True,
                                preexec_fn=dies_with_parent(signal.SIGTERM))


# Domains a run may be given: 0, ROS's default, is left to whatever else runs ROS on the host. Above 101
# Fast DDS's ports for a domain run into Linux's ephemeral range.
FRESH_DOMAINS = range(1, 102)
DOMAIN_CLAIMS = Path(tempfile.gettempdir()) / 'uav-flock-domains'


class DomainInUse(Exception):
    """Every domain asked for is held by another run on this host."""


class DomainClaim:
    """A ROS_DOMAIN_ID held for one run, released on release(), on leaving a with block, or when the process ends.

    Two runs in one domain would hear each other's MAPs: their topics have the same names. The claim is
    an flock on one file per domain, which the kernel drops with the process, so a SIGKILLed run frees
    its domain at once and nothing stale is left to clean.
    """

    def __init__(self, domain: int, fd: int) -> None:
        self.domain, self._fd = domain, fd

    def release(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def __enter__(self) -> int:
        return self.domain

    def __exit__(self, *exc: object) -> None:
        self.release()


def claim_domain(requested: Optional[int] = None) -> DomainClaim:
    """The requested domain, or a random free one of FRESH_DOMAINS; DomainInUse if another run holds it."""
    if not DOMAIN_CLAIMS.is_dir():
        DOMAIN_CLAIMS.mkdir(exist_ok=True)
        os.chmod(DOMAIN_CLAIMS, 0o1777)  # shared by every user of the host, as DDS domains are
    candidates = [requested] if requested is not None else random.SystemRandom().sample(FRESH_DOMAINS,
                                                                                        len(FRESH_DOMAINS))
    for domain in candidates:
        fd = os.open(DOMAIN_CLAIMS / str(domain), os.O_RDONLY | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            continue
        return DomainClaim(domain, fd)
    if requested is not None:
        raise DomainInUse(f'ROS_DOMAIN_ID {requested} is in use by another run on this host')
    raise DomainInUse(f'every ROS_DOMAIN_ID from {FRESH_DOMAINS[0]} to {FRESH_DOMAINS[-1]} is in use by '
                      'another run on this host')


def write_pid_table(path: Path, table: dict[int, int]) -> None:
    tmp = path.with_suffix('.tmp')
    tmp.write_text(json.dumps({str(k): v for k, v in sorted(table.items())}, indent=1))
    tmp.replace(path)


def read_pid_table(run: Path) -> dict[int, int]:
    path = run / 'pids.json'
    if not path.exists():
        raise FileNotFoundError(f'{run}: no pids.json (is it a run folder of ./uav-flock up?)')
    return {int(k): int(v) for k, v in json.loads(path.read_text()).items()}


# Agent processes are forked from a template process that has imported rclpy, numpy, scipy and the agent
# once (multiprocessing's forkserver), not started afresh: a fresh Python process spends 0.8 CPU-s on those
# imports, which is 36 s of a two-core machine for 90 MAPs (docs/benchmarks.md). Each fork is a process of
# its own (own pid, own session, own DDS participant) that really dies when killed.
AGENT_TEMPLATE_MODULES = ['uav_flock_tools.agent_template', 'uav_flock_tools.launcher']


def agent_process(argv: list[str], env: dict[str, str], log: str, up_pid: int) -> None:
    """Body of a forked agent process: its own session, log file and run environment, then the agent's main."""
    os.setsid()  # a process group of its own, as start_new_session gives a Popen child
    end_with(up_pid, signal.SIGTERM)
    setproctitle(' '.join(argv))  # what `ps` and `pkill -f` see: the command line of the console script
    fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    os.environ.clear()
    os.environ.update(env)  # before rclpy.init: the domain, discovery and transports of this run
    from uav_agent.agent_node import main
    sys.exit(main(argv))


class ForkedAgent:
    """An agent process forked by the template, with the part of Popen's interface that `stop` uses."""

    def __init__(self, proc: multiprocessing.process.BaseProcess) -> None:
        self.proc = proc
        self.pid = proc.pid

    def poll(self) -> Optional[int]:
        return self.proc.exitcode

    def wait(self, timeout: Optional[float] = None) -> int:
        self.proc.join(timeout)
        if self.proc.exitcode is None:
            raise subprocess.TimeoutExpired(f'agent process {self.pid}', timeout or 0.0)
        return self.proc.exitcode


def agent_argv(ids: Sequence[int], params: Path) -> list[str]:
    """The agent node's command line: one process serving `ids`, parameters from the run's params file."""
    return ['uav_agent_node', '--ids', ','.join(map(str, ids)), '--ros-args', '--params-file', str(params)]


def start_agent(ids: Sequence[int], params: Path, env: dict[str, str], log: IO[str]) -> subprocess.Popen:
    """Start one agent process as a direct child (replay's single MAP), where `start_agents` forks many.

    A direct child, not a fork of the template, so the caller's pid is its parent's and a `kill` of the
    caller ends it by the parent-death signal.
    """
    argv = agent_argv(ids, params)
    return subprocess.Popen([executable('uav_agent', argv[0]), *argv[1:]], env=env, stdout=log,
                            stderr=subprocess.STDOUT, start_new_session=True,
                            preexec_fn=dies_with_parent(signal.SIGTERM))


def start_agents(id_groups: list[list[int]], params: Path, env: dict[str, str], logs: Path,
                 into: list[ForkedAgent], stop_if: Callable[[], bool]) -> None:
    """Fork one agent process per group of MAP ids from the template process, into `into` as each starts.

    `stop_if` is asked before each fork: a Ctrl-C is acted on between forks, never inside one, where the
    new process would escape the list that `up` stops.
    """
    ctx = multiprocessing.get_context('forkserver')
    ctx.set_forkserver_preload(AGENT_TEMPLATE_MODULES)
    for ids in id_groups:
        if stop_if():
            return
        argv = agent_argv(ids, params)
        proc = ctx.Process(target=agent_process, args=(argv, env, str(logs / f'agents_{ids[0]}.log'), os.getpid()),
                           name=f'agents_{ids[0]}')
        proc.start()
        into.append(ForkedAgent(proc))


Stoppable = Union[subprocess.Popen, ForkedAgent]


def _signal(p: Stoppable, sig: int) -> None:
    """Signal p's process group, or p alone while it has none yet (a fork that has not reached setsid)."""
    try:
        os.killpg(p.pid, sig)
    except ProcessLookupError:
        try:
            os.kill(p.pid, sig)
        except ProcessLookupError:
            pass


def stop(procs: Sequence[Stoppable], first: int = signal.SIGTERM,
         also: Optional[dict[int, list[subprocess.Popen]]] = None) -> None:
    """Signal (`also` maps other signals to other processes), wait up to GRACE_S, then SIGKILL and reap.

    All are signalled at once, so that a run of a hundred processes still ends within one grace period.
    """
    groups: dict[int, Sequence[Stoppable]] = {first: list(procs), **(also or {})}
    every = [p for group in groups.values() for p in group]
    for sig, group in groups.items():
        for p in group:
            if p.poll() is None:
                _signal(p, sig)
    deadline = time.monotonic() + GRACE_S
    for p in every:
        try:
            p.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            pass
    for p in every:
        if p.poll() is None:
            _signal(p, signal.SIGKILL)
            p.wait()


SHM_DIR = Path('/dev/shm')


def clean_shared_memory(env: dict[str, str], since: Optional[float] = None) -> None:
    """Remove the shared-memory files of participants that ended without removing them.

    With LOCALHOST discovery the participants talk over /dev/shm. A SIGKILLed one cannot remove its
    segment, and its peers do not always do it for it. Fast DDS's own tool removes every segment and port
    file whose lock no living process holds; it leaves those of running participants alone.

    It knows only ports that a listener locked, though. A sender makes the file of the port it writes to,
    and when that listener was SIGKILLed, or never came up (Ctrl-C at start-up), the file stays without a
    lock. With `since`, such lockless port files made since then that no process has mapped go too.
    """
    try:
        subprocess.run(['fastdds', 'shm', 'clean'], env=env, capture_output=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired) as exc:
        print(f'uav-flock up: could not clean shared memory ({exc}); `fastdds shm clean` does it by hand',
              file=sys.stderr)
    if since is not None:
        for port in _orphan_ports(since):
            for path in (SHM_DIR / port, SHM_DIR / f'sem.{port}_mutex'):
                path.unlink(missing_ok=True)


def _orphan_ports(since: float) -> list[str]:
    """Port files (fastrtps_port<N>) with no lock file, made since `since`, that no living process maps."""
    try:
        names = set(os.listdir(SHM_DIR))
    except OSError:
        return []
    candidates = []
    for name in names:
        if (name.startswith('fastrtps_port') and name[len('fastrtps_port'):].isdigit()
                and f'{name}_el' not in names and f'{name}_sl' not in names):
            try:
                if (SHM_DIR / name).stat().st_mtime >= since:
                    candidates.append(name)
            except OSError:
                pass
    if not candidates:
        return []
    mapped: set[str] = set()
    for pid in filter(str.isdigit, os.listdir('/proc')):
        try:
            with open(f'/proc/{pid}/maps') as maps:
                mapped.update(line.rsplit('/', 1)[-1].strip() for line in maps if '/dev/shm/fastrtps_port' in line)
        except OSError:  # gone meanwhile, or not ours to read
            pass
    return [c for c in candidates if c not in mapped]


ROS_LOG_LINE = re.compile(r'^\[(WARN|ERROR|FATAL)\] \[[\d.]+\] (.*)$')


def relay_log(stream: IO[str], log: Path) -> threading.Thread:
    """A node's console log into its file, and its warnings and errors to our stderr as they come.

    A dropped MAP, a stalled step or a recorder gone must not wait for someone to open the log file.
    """
    def pump() -> None:
        with open(log, 'w') as out:
            for line in stream:
                out.write(line)
                out.flush()
                if m := ROS_LOG_LINE.match(line):  # without the timestamp, which says nothing here
                    print(f'[{m[1]}] {m[2]}', file=sys.stderr, flush=True)
    thread = threading.Thread(target=pump, name=f'relay {log.name}', daemon=True)
    thread.start()
    return thread


def describe_exit(code: int) -> str:
    return f'killed by {signal.Signals(-code).name}' if code < 0 else f'exit {code}'


def scenario_summary(path: Path, s: Scenario) -> dict[str, object]:
    """What a bag says about the run it holds, beside the agents' parameters."""
    return {'scenario': Path(path).name, 'maps': s.maps, 'seed': s.seed, 'dt': s.dt, 'duration': s.duration,
            'fail_at': s.fail_at, 'fail_fraction': s.fail_fraction, 'association': s.association}


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

    @property
    def bag_path(self) -> Path:
        return self.run / 'bag'

    @property
    def logs(self) -> Path:
        return self.run / 'logs'


def plan(scenario_path: Path, scenario: Scenario, run: Path, agents_per_process: int, domain_id: Optional[int],
         discovery: str, record: bool, sync: str, rate: float, listen: Optional[str] = None,
         agents_here: Optional[int] = None) -> Plan:
    """Stage 1: decide the run (and claim its ROS_DOMAIN_ID, held until every process of it has ended).

    With listen (an address of this host that the others reach), the discovery server listens there and
    MAPs agents_here.. are left to agents that join from other hosts.
    """
    if record and (run / 'bag').exists():
        raise FileExistsError(f'{run / "bag"} exists already: give a new --out folder')
    here = scenario.maps if agents_here is None else min(agents_here, scenario.maps)
    groups = [list(range(first, min(first + agents_per_process, here))) for first in range(0, here, agents_per_process)]
    processes = len(groups) + 1 + int(record)
    use_server = listen is not None or discovery == 'server' or (
        discovery == 'auto' and (processes > LOCALHOST_LIMIT or scenario.maps > LOCALHOST_MAPS_LIMIT))
    claim = claim_domain(domain_id)
    server_address = discovery_server_address(claim.domain, listen or '127.0.0.1') if use_server else None
    discovery_range = 'SUBNET' if discovery == 'subnet' else 'LOCALHOST'
    timeout = max(START_TIMEOUT_MIN_S, START_TIMEOUT_PER_PROCESS_S * processes)
    if listen is not None:  # time for someone to start the agents on the other hosts
        timeout = max(timeout, JOIN_TIMEOUT_S)
    return Plan(scenario_path, scenario, run, agents_per_process, record, sync, rate, claim, server_address,
                discovery_range, ros_env(claim.domain, server_address, discovery_range), timeout, groups,
                list(range(here, scenario.maps)))


class Run:
    """Stages 2 to 5 of `up`: write the run's files, start its processes, supervise, stop them all.

    A Ctrl-C (or SIGTERM) while a process is being started waits until that process is in hand, so that
    nothing escapes the stop; at any other time it ends supervision at once.
    """

    def __init__(self, p: Plan) -> None:
        self.p = p
        self.info: dict[str, object] = {}
        self.agents: list[ForkedAgent] = []
        self.world: Optional[subprocess.Popen] = None
        self.world_log: Optional[threading.Thread] = None
        self.recorder: Optional[subprocess.Popen] = None
        self.server: Optional[subprocess.Popen] = None
        self.recorder_gone: Optional[int] = None
        self.interrupted = self.starting = self.stopping = False
        self.began_at = time.time()  # wall clock, as file times are

    # ------------------------------------------------------------------ 2. files
    def write_files(self) -> Path:
        """agent_params.yaml, run.json and logs/; returns the agents' parameter file."""
        p, s = self.p, self.p.scenario
        p.run.mkdir(parents=True, exist_ok=True)
        agent_params = {**s.flock.as_dict(), 'sync': p.sync, 'world_start_timeout': 2 * p.start_timeout}
        params = write_params(p.run / 'agent_params.yaml', agent_params)
        self.info = {'domain_id': p.claim.domain, 'discovery_server': p.server_address,
                     'discovery_range': None if p.server_address else p.discovery_range,
                     'scenario': str(p.scenario_path), 'maps': s.maps, 'seed': s.seed,
                     'agents_per_process': p.agents_per_process, 'sync': p.sync,
                     'rate': p.rate if p.sync == 'realtime' else None,
                     'bag': str(p.bag_path) if p.record else None}
        if p.remote:
            self.info['remote_ids'] = [p.remote[0], p.remote[-1]]
            # What `agents --join` fetches from /run_info: the MAPs it may serve and the agents' parameters.
            (p.run / 'join.json').write_text(json.dumps({
                'maps': s.maps, 'remote_ids': [p.remote[0], p.remote[-1]], 'domain_id': p.claim.domain,
                'agent_params': agent_params}))
        self.write_info()
        p.logs.mkdir(exist_ok=True)
        pace = f'realtime x{p.rate:g}' if p.sync == 'realtime' else 'lockstep'
        print(f'uav-flock up: {s.maps} MAPs in {len(p.groups)} processes, {pace}, ROS_DOMAIN_ID={p.claim.domain}, '
              f'discovery {"server " + p.server_address if p.server_address else p.discovery_range}, '
              f'run folder {p.run}', flush=True)
        if p.remote:
            print(f'uav-flock up: MAPs {p.remote[0]}-{p.remote[-1]} join from other hosts: ./uav-flock agents '
                  f'--join {p.server_address} --ids {p.remote[0]}-{p.remote[-1]} (waiting {p.start_timeout:.0f} s)',
                  flush=True)
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
            self.server = start_discovery_server(p.server_address, p.env, p.logs / 'discovery_server.log')
            self.info['discovery_server_pid'] = self.server.pid
        self.raise_if_interrupted()
        if p.record:
            rec_params = write_params(p.run / 'recorder_params.yaml', {
                'out': str(p.bag_path), 'maps': s.maps, 'sync': p.sync, 'params_json': json.dumps(s.flock.as_dict()),
                'scenario_json': json.dumps({**scenario_summary(p.scenario_path, s), 'sync': p.sync})})
            # With a discovery server, a plain client hears only of the topics it already uses; the recorder
            # finds its topics in the graph, so it is a super-client, which hears of every endpoint.
            self.recorder = subprocess.Popen(
                [executable('uav_flock_tools', 'uav_flock_recorder'), '--ros-args', '--params-file', str(rec_params)],
                env={**p.env, 'ROS_SUPER_CLIENT': 'TRUE'} if p.server_address else p.env,
                stdout=open(p.logs / 'recorder.log', 'w'), stderr=subprocess.STDOUT, start_new_session=True,
                preexec_fn=dies_with_parent(signal.SIGINT))
            self.raise_if_interrupted()
        world_args = [executable('world_sim', 'world_sim_node'), '--ros-args',
                      '-p', f'scenario:={p.scenario_path}', '-p', f'maps:={s.maps}',
                      '-p', f'seed:={s.seed}', '-p', f'duration:={float(s.duration)}', '-p', f'out:={p.run}',
                      '-p', f'pid_table:={p.run / "pids.json"}', '-p', f'start_timeout:={p.start_timeout}',
                      '-p', f'sync:={p.sync}', '-p', f'rate:={float(p.rate)}']
        if p.record:
            world_args += ['-p', 'record:=true']
        if s.fail_at is not None:
            world_args += ['-p', f'fail_at:={float(s.fail_at)}', '-p', f'fail_fraction:={float(s.fail_fraction)}']
        if p.remote:
            world_args += ['-p', f'run_info:={p.run / "join.json"}']
        self.world = subprocess.Popen(world_args, env=p.env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
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
        return self.world.wait()

    # ------------------------------------------------------------------ 5. stop
    def stop_all(self) -> None:
        """World and agents together, the world signalled first (SIGINT: it writes its records and takes the
        agents' ends for the stop, not for failures); the recorder once the world has published its last,
        then it drains and closes the bag; the discovery server last."""
        self.stopping = True
        self.recorder_gone = self.recorder.poll() if self.recorder is not None else None  # ends only when told
        stop([self.world] if self.world is not None else [], signal.SIGINT, {signal.SIGTERM: self.agents})
        if self.recorder is not None:
            stop([self.recorder], signal.SIGINT)
        if self.server is not None:
            stop([self.server])
        # A SIGKILLed agent cannot remove its files, nor can one stopped while its participant was still
        # being made (Ctrl-C during start-up left some behind).
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
       agents_here: Optional[int] = None) -> tuple[int, Optional[RunResult]]:
    """Run the scenario distributed, in stages; returns (exit code, result read back from the run folder)."""
    r = Run(plan(scenario_path, scenario, run, agents_per_process, domain_id, discovery, record, sync, rate,
                 listen, agents_here))
    old_int, old_term = signal.signal(signal.SIGINT, r.on_signal), signal.signal(signal.SIGTERM, r.on_signal)
    try:
        try:
            r.start(r.write_files())
            code = r.supervise()
        except KeyboardInterrupt:
            code = 130
        finally:
            r.stop_all()
        # Still under our handler, which ignores a Ctrl-C from the stop on: one that came just after the
        # processes ended must not cut the report short.
        return r.report(code), read_result(run, scenario)
    finally:
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGTERM, old_term)


def read_result(run: Path, scenario: Scenario) -> Optional[RunResult]:
    """The run's records as a RunResult, from the files world_sim wrote (None if it wrote none)."""
    if not all((run / f).exists() for f in ('metrics.csv', 'trajectory.csv', records.USERS_FILE,
                                            records.FAILURES_FILE)):
        return None
    m = records.read_csv(run / 'metrics.csv')
    if len(m['step']) == 0:
        return None
    t = records.read_csv(run / 'trajectory.csv')
    metrics = records.rows(m, records.METRICS_COLUMNS)
    traj = records.rows(t, records.TRAJECTORY_COLUMNS)
    failed, fail_step = records.read_failures(run / records.FAILURES_FILE)
    return RunResult(scenario, records.read_users(run / records.USERS_FILE), metrics, traj, failed, fail_step,
                     records.read_motion(run / records.USERS_FILE))


def kill(run: Path, ids: Optional[list[int]], fraction: Optional[float], whole_processes: bool = False
         ) -> tuple[list[int], list[int]]:
    """SIGKILL agent processes of a running `up`: by MAP id, or a random fraction of the live MAPs.

    Returns (MAP ids killed, pids killed). A SIGKILL takes every MAP of a process: with agents packed
    several to a process, asking for some of them is refused (ValueError naming the others), unless
    whole_processes says to take all MAPs of the processes concerned.
    """
    if run_has_ended(run):
        raise ValueError(f'the run in {run} has ended: nothing to kill')
    table = read_pid_table(run)
    params = run.resolve() / 'agent_params.yaml'
    live = sorted(i for i, pid in table.items() if agent_of_run(pid, params))
    by_pid: dict[int, list[int]] = {}
    for i in live:
        by_pid.setdefault(table[i], []).append(i)
    if ids is None:
        count = int(round((fraction or 0.0) * len(live)))
        if all(len(maps) == 1 for maps in by_pid.values()):
            ids = sorted(random.SystemRandom().sample(live, count))
        elif not whole_processes:
            raise ValueError(f'--fraction: agents are packed up to {max(map(len, by_pid.values()))} to a process '
                             'and a SIGKILL takes them all; pass --whole-processes to kill whole processes '
                             f'holding about {count} MAPs')
        else:
            ids = []
            for pid in random.SystemRandom().sample(sorted(by_pid), len(by_pid)):
                if len(ids) >= count:
                    break
                ids += by_pid[pid]
    unknown = [i for i in ids if i not in table]
    if unknown:
        raise ValueError(f'--ids: no MAP {unknown[0]} in this run (ids 0-{max(table)})')
    pids = sorted({table[i] for i in ids if i in live})
    taken = sorted(i for pid in pids for i in by_pid[pid])
    extra = sorted(set(taken) - set(ids))
    if extra and not whole_processes:
        first = next(i for i in ids if i in live and set(by_pid[table[i]]) - set(ids))
        others = sorted(set(by_pid[table[first]]) - set(ids))
        raise ValueError(f'--ids: MAP {first} shares its process (pid {table[first]}) with MAPs {others}, which a '
                         f'SIGKILL takes too; ask for them as well, or pass --whole-processes (MAPs {taken} would die)')
    for pid in pids:
        os.kill(pid, signal.SIGKILL)
    return taken, pids


def _running(pid: int, *words: str) -> bool:
    """A living process whose command line holds all of words: a pid alone may since belong to another."""
    from uav_flock_ros.processes import process_alive
    try:
        line = Path(f'/proc/{pid}/cmdline').read_bytes().replace(b'\0', b' ').decode(errors='replace')
    except OSError:
        return False
    return all(w in line for w in words) and process_alive(pid)


def agent_of_run(pid: int, params: Path) -> bool:
    """A living agent process of the run whose parameter file this is.

    After a run has ended its pids may belong to other processes: `kill --run` on an old run must not
    SIGKILL them. Every agent's command line names its run's agent_params.yaml.
    """
    return _running(pid, 'uav_agent_node', f'--params-file {params}')


def run_has_ended(run: Path) -> bool:
    """The run's world_sim is gone, so are its topics. False while unknown (world not yet started)."""
    try:
        pid = json.loads((run / 'run.json').read_text()).get('world_pid')
    except (OSError, ValueError, AttributeError):
        return False
    return isinstance(pid, int) and not _running(pid, 'world_sim_node', f' out:={run.resolve()} ')
