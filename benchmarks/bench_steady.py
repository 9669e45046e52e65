"""Where a lockstep run's CPU goes once it is under way: per step, by process role, start-up left out.

Run: ./uav-flock exec python benchmarks/bench_steady.py [MAPS[:PER_PROCESS]] [--window FROM:TO]
(default: 90 MAPs, one process each, simulated seconds 10 to 20, the paper scenario). The benchmark runs
`up --maps MAPS --agents-per-process PER_PROCESS --duration TO`, reads the CPU time of every process of
the run when the progress line for FROM and for TO comes out, and prints the CPU time per step of the
agents, world_sim and the discovery server, the wall time of the window, and how much of the two cores
stayed idle. bench_runtime.py's figures include start-up and step 0; these do not.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import NamedTuple, NoReturn

from uav_flock_tools.spawn import read_pid_table
from world_sim.core import records

PROGRESS = re.compile(r'^t = +([0-9.]+) s')
TICK = os.sysconf('SC_CLK_TCK')


class Snapshot(NamedTuple):
    wall: float
    idle: float  # core-seconds the machine has been idle since boot
    cpu: dict[str, float]  # role -> user + system seconds


def usage_error(message: str) -> NoReturn:
    print(f'bench_steady: error: {message}', file=sys.stderr)
    sys.exit(2)


def process_cpu(pid: int) -> float:
    """User + system seconds of every thread of pid so far; 0 for a process that is gone."""
    try:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / TICK


def snapshot(run: Path) -> Snapshot:
    info = json.loads((run / 'run.json').read_text())
    roles = {'agents': sorted(set(read_pid_table(run).values())), 'world_sim': [int(info['world_pid'])]}
    if info.get('discovery_server_pid'):
        roles['discovery server'] = [int(info['discovery_server_pid'])]
    idle = int(Path('/proc/stat').read_text().split()[4]) / TICK
    return Snapshot(time.monotonic(), idle, {role: sum(map(process_cpu, pids)) for role, pids in roles.items()})


def main() -> None:
    parser = argparse.ArgumentParser(prog='bench_steady', description=__doc__.split('\n')[0])
    parser.add_argument('config', nargs='?', default='90:1', help='MAPS[:PER_PROCESS] (default 90:1)')
    parser.add_argument('--window', default='10:20', help='FROM:TO in simulated seconds (default 10:20)')
    args = parser.parse_args()
    try:
        maps, per = (int(v) for v in (args.config + ':1').split(':')[:2])
        start, end = (float(v) for v in args.window.split(':'))
    except ValueError:
        usage_error(f'expected MAPS[:PER_PROCESS] and --window FROM:TO, got {args.config!r} and {args.window!r}')
    if maps < 1 or per < 1 or not 0 <= start < end:
        usage_error('MAPS and PER_PROCESS must be positive, and FROM must be below TO')
    run = Path(tempfile.mkdtemp(prefix='bench_steady.'))
    proc = subprocess.Popen([sys.executable, '-m', 'uav_flock_tools.cli', 'up', '--maps', str(maps),
                             '--agents-per-process', str(per), '--duration', f'{end:g}', '--out', str(run)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    marks: dict[float, Snapshot] = {}
    assert proc.stdout is not None
    try:
        for line in proc.stdout:
            print(f'  {line.rstrip()}', file=sys.stderr, flush=True)
            if (m := PROGRESS.match(line)) and float(m[1]) in (start, end) and float(m[1]) not in marks:
                marks[float(m[1])] = snapshot(run)
        proc.wait()
    except KeyboardInterrupt:  # `up` got the Ctrl-C too and ends its run
        proc.wait()
        print(f'bench_steady: interrupted; the run is in {run}', file=sys.stderr)
        sys.exit(130)
    if proc.returncode != 0 or len(marks) < 2:
        print(f'bench_steady: error: the run ended (exit {proc.returncode}) before t = {end:g} s; see {run}/logs',
              file=sys.stderr)
        sys.exit(1)
    a, b = marks[start], marks[end]
    t = records.read_csv(run / 'metrics.csv')['t']
    steps = int(((t > start + 1e-9) & (t <= end + 1e-9)).sum())
    wall = b.wall - a.wall
    print(f'{maps} MAPs, {per} per process, t = {start:g}..{end:g} s ({steps} steps): wall {wall:.1f} s, '
          f'{steps / wall:.2f} steps/s, real-time factor {(end - start) / wall:.2f}')
    total = 0.0
    for role in a.cpu:
        cpu = b.cpu[role] - a.cpu[role]
        total += cpu
        print(f'  {role:16s} {cpu:6.1f} CPU-s  {1000 * cpu / steps:6.1f} ms/step  {1000 * cpu / (steps * maps):5.2f} ms/MAP-step')
    cores = os.cpu_count() or 1
    print(f'  {"all of the run":16s} {total:6.1f} CPU-s  {1000 * total / (steps * maps):5.2f} ms/MAP-step; '
          f'machine idle {b.idle - a.idle:.1f} of {cores * wall:.1f} core-s')
    print(f'  at this CPU per step, {cores} fully used cores would make {cores * steps / total:.1f} steps/s '
          f'(real-time factor {cores * (end - start) / total:.2f})')


if __name__ == '__main__':
    main()
