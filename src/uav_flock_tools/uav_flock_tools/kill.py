"""`./uav-flock kill`: SIGKILL some MAPs of a running run, as a failure would, and tell a run that has ended."""
from __future__ import annotations

import json
import os
import random
import signal
from pathlib import Path
from typing import Optional

from uav_flock_ros.processes import CRASH_DIR

from .spawn import read_pid_table


def kill(run: Path, ids: Optional[list[int]], fraction: Optional[float], whole_processes: bool = False
         ) -> tuple[list[int], list[int], list[int]]:
    """Kill MAPs of a running `up`, by id or a random fraction of the live ones, as a failure would.

    Returns (MAP ids killed, pids whose named MAPs' nodes ended inside them, pids SIGKILLed whole). A MAP alone in its process dies by
    SIGKILL with it. A MAP packed with others has its node ended inside the process, as abruptly (no last
    message, nothing flushed; see agent_process.CrashRequests), and the other MAPs fly on; whole_processes
    instead SIGKILLs every process concerned with all of its MAPs.
    """
    if run_has_ended(run):
        raise ValueError(f'the run in {run} has ended: nothing to kill')
    table = read_pid_table(run)
    params = run.resolve() / 'agent_params.yaml'
    crashed = run / CRASH_DIR
    live = sorted(i for i, pid in table.items() if agent_of_run(pid, params) and not (crashed / str(i)).exists())
    by_pid: dict[int, list[int]] = {}
    for i in live:
        by_pid.setdefault(table[i], []).append(i)
    if ids is None:
        count = int(round((fraction or 0.0) * len(live)))
        if not whole_processes:
            ids = sorted(random.SystemRandom().sample(live, count))
        else:
            ids = []
            for pid in random.SystemRandom().sample(sorted(by_pid), len(by_pid)):
                if len(ids) >= count:
                    break
                ids += by_pid[pid]
    unknown = [i for i in ids if i not in table]
    if unknown:
        raise ValueError(f'--ids: no MAP {unknown[0]} in this run (ids 0-{max(table)})')
    dead = [i for i in ids if i not in live]
    if dead:
        raise ValueError(f'--ids: MAP{"s" if len(dead) > 1 else ""} {", ".join(map(str, dead))} '
                         f'{"are" if len(dead) > 1 else "is"} not alive (live: {live or "none"})')
    if not ids:
        raise ValueError(f'--fraction {fraction:g} of {len(live)} live MAPs is no MAP: nothing to kill')
    pids = sorted({table[i] for i in ids})
    # A process whose every live MAP is asked for dies whole, as it would in a crash of its host's software.
    whole = [pid for pid in pids if whole_processes or set(by_pid[pid]) <= set(ids)]
    crashed.mkdir(exist_ok=True)
    for pid in pids:
        if pid not in whole:
            for i in ids:
                if table[i] == pid:
                    (crashed / str(i)).touch()
            os.kill(pid, signal.SIGUSR1)
    for pid in whole:
        os.kill(pid, signal.SIGKILL)
    taken = sorted({*ids, *(i for pid in whole for i in by_pid[pid])})
    return taken, [pid for pid in pids if pid not in whole], whole


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
