"""Starting a run's processes and ending them: console scripts as children that die with their parent, agent
processes forked from a template, pid tables, and a stop that leaves nothing running."""
from __future__ import annotations

import ctypes
import json
import multiprocessing
import os
import re
import select
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO, Callable, Optional, Sequence, Union

from setproctitle import setproctitle

GRACE_S = 3.0  # after SIGINT/SIGTERM, how long children get before SIGKILL



def executable(package: str, name: str) -> str:
    """The console script `ros2 run package name` would start."""
    from ament_index_python.packages import get_package_prefix
    return os.path.join(get_package_prefix(package), 'lib', package, name)


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
AGENT_TEMPLATE_MODULES = ['uav_flock_tools.agent_template', 'uav_flock_tools.spawn']


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
    from uav_agent.agent_process import main
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


def describe_exit(code: int) -> str:
    return f'killed by {signal.Signals(-code).name}' if code < 0 else f'exit {code}'


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
