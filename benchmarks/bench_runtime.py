"""Distributed runs of the paper scenario: wall time, real-time factor, start-up, memory and CPU.

Run: ./uav-flock exec python benchmarks/bench_runtime.py [MAPS:PER_PROCESS[:record][:realtime][:view][:xRATE][:dSECONDS] ...]
(default: the runs the distributed runtime is judged by, 300 steps of 90 MAPs with 1, 10 and 45 agents per
process, and 50 steps of 200 MAPs with 20 per process, about 10 minutes in all). With ':record' the run also writes its bag (`up --record`); when a configuration
is given with and without it, the cost of recording is printed as the ratio of the two wall times.
':realtime' runs `up --sync realtime` (rate 1, or ':x0.5' for half real time); ':d20' simulates 20 s
instead of the scenario's 60; ':view' runs with the live view (`up --view`) and one WebSocket client subscribed
to its scene and metrics the whole run, and prints how many scenes the client received.
A realtime run also prints whether λ2 > 0 at every step from the first where the simulator's is, to the end.
A lockstep run is checked against the batch simulator (trajectory equal to the byte); every run prints
its final coverage and Fiedler value beside the simulator's.
"""
from __future__ import annotations

import ctypes
import os
import re
import resource
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import NamedTuple, NoReturn, Optional

from uav_flock_tools.spawn import read_pid_table
from world_sim.core import records


def memory_mb(pids: set[int]) -> dict[int, tuple[float, float]]:
    """(peak RSS, PSS now) of each process. Forked agents share the template's pages, which RSS counts in
    full for every process and PSS divides among those that share them."""
    out = {}
    for pid in pids:
        try:
            hwm = next(int(line.split()[1]) for line in Path(f'/proc/{pid}/status').read_text().splitlines()
                       if line.startswith('VmHWM:'))
            pss = next(int(line.split()[1]) for line in Path(f'/proc/{pid}/smaps_rollup').read_text().splitlines()
                       if line.startswith('Pss:'))
        except (OSError, StopIteration):
            continue
        out[pid] = (hwm / 1024, pss / 1024)
    return out


def reap_orphans() -> None:
    """Wait for the descendants that were reparented to us (see main), so that their CPU time is counted."""
    while True:
        try:
            os.waitpid(-1, 0)
        except ChildProcessError:
            return


FRESH = re.compile(r'fresh commands (\d+) %')
PROGRESS = re.compile(r't = +([0-9.]+) s ')


class Config(NamedTuple):
    maps: int
    per: int
    record: bool
    realtime: bool
    rate: float
    duration: Optional[float]
    view: bool = False


DEFAULT_CONFIGS = ('90:1:d30', '90:10:d30', '90:45:d30', '200:20:d5')


def parse(config: str) -> Config:
    """MAPS:PER_PROCESS[:flags]; a malformed one ends the benchmark with a one-line error."""
    try:
        maps, per, *flags = config.split(':')
        unknown = [f for f in flags if f not in ('record', 'realtime', 'view') and f[:1] not in ('d', 'x')]
        if unknown:
            raise ValueError(f'unknown flag {unknown[0]!r}')
        duration = next((float(f[1:]) for f in flags if f.startswith('d')), None)
        rate = next((float(f[1:]) for f in flags if f.startswith('x')), 1.0)
        c = Config(int(maps), int(per), 'record' in flags, 'realtime' in flags, rate, duration, 'view' in flags)
    except ValueError as exc:
        usage_error(f'{config!r}: expected MAPS:PER_PROCESS[:record][:realtime][:view][:xRATE][:dSECONDS] ({exc})')
    if c.maps < 1 or c.per < 1 or c.rate <= 0 or (c.duration is not None and c.duration <= 0):
        usage_error(f'{config!r}: MAPS, PER_PROCESS, RATE and SECONDS must be positive')
    return c


def usage_error(message: str) -> NoReturn:
    """One line and exit code 2, as the uav-flock commands do."""
    print(f'bench_runtime: error: {message}', file=sys.stderr)
    sys.exit(2)


def final(metrics: Path) -> tuple[float, float]:
    """Coverage and Fiedler value at the run's last step."""
    m = records.read_csv(metrics)
    return float(m['coverage_ratio'][-1]), float(m['fiedler'][-1])


def watch(port: int, done: threading.Event, seen: list[int]) -> None:
    """One Foxglove WebSocket client for the whole run: subscribes to /scene and /metrics, counts scenes."""
    import asyncio
    import json

    import websockets

    async def client() -> None:
        while not done.is_set():
            try:
                ws = await websockets.connect(f'ws://127.0.0.1:{port}', subprotocols=['foxglove.sdk.v1'])
                break
            except OSError:
                await asyncio.sleep(0.2)
        else:
            return
        async with ws:
            chans: dict[str, int] = {}
            while not done.is_set():
                try:
                    msg = await asyncio.wait_for(ws.recv(), 0.5)
                except asyncio.TimeoutError:
                    continue
                except websockets.ConnectionClosed:
                    return
                if isinstance(msg, str) and json.loads(msg)['op'] == 'advertise':
                    new = {c['topic']: c['id'] for c in json.loads(msg)['channels'] if c['topic'] in ('/scene', '/metrics')}
                    await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
                        {'id': i, 'channelId': cid} for i, cid in enumerate(new.values(), len(chans))]}))
                    chans.update(new)
                elif isinstance(msg, bytes) and msg[0] == 1 and int.from_bytes(msg[1:5], 'little') == 0:
                    seen[0] += 1
    asyncio.run(client())


def free_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return int(s.getsockname()[1])


def run(c: Config, folder: Path) -> dict[str, float]:
    maps, per_process, record, realtime, duration = c.maps, c.per, c.record, c.realtime, c.duration
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    port = free_port()
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, '-m', 'uav_flock_tools.cli', 'up', '--maps', str(maps),
                             '--agents-per-process', str(per_process), '--out', str(folder)]
                            + (['--record'] if record else []) + (['--sync', 'realtime', '--rate', str(c.rate)] if realtime else [])
                            + (['--duration', str(duration)] if duration else []) + (['--view', str(port)] if c.view else []),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    done, scenes = threading.Event(), [0]
    viewer = threading.Thread(target=watch, args=(port, done, scenes), daemon=True)
    if c.view:
        viewer.start()
    first_step = None
    last_step = (0.0, 0.0)  # (simulated s, wall s) of the last progress line: the run's pace, not its shutdown
    fresh: list[int] = []
    peaks: dict[int, float] = {}
    pss: dict[int, float] = {}

    def sample() -> None:
        while proc.poll() is None:
            if (folder / 'pids.json').exists():
                try:
                    for pid, (hwm, now) in memory_mb(set(read_pid_table(folder).values())).items():
                        peaks[pid] = max(peaks.get(pid, 0.0), hwm)
                        pss[pid] = max(pss.get(pid, 0.0), now)
                except ValueError:
                    pass
            time.sleep(1.0)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    assert proc.stdout is not None
    for line in proc.stdout:
        print(f'  [{c.maps}:{c.per}] {line.rstrip()}', file=sys.stderr, flush=True)  # progress of a long run
        if first_step is None and line.startswith('t =   0.0 s'):
            first_step = time.monotonic() - t0
        if (m := PROGRESS.match(line)) and first_step is not None:
            last_step = (float(m[1]), time.monotonic() - t0)
        if (m := FRESH.search(line)) and not line.startswith('t =   0.0 s'):
            fresh.append(int(m[1]))
    proc.wait()
    wall = time.monotonic() - t0
    done.set()
    reap_orphans()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = records.read_csv(folder / 'metrics.csv')['t']
    sim_s = float(t[-1])
    paced = first_step is not None and last_step[0] > 0
    return {'wall': wall, 'first': first_step or float('nan'),
            'rtf': last_step[0] / (last_step[1] - first_step) if paced else float('nan'),
            'rss': max(peaks.values()) if peaks else float('nan'),
            'pss': max(pss.values()) if pss else float('nan'), 'processes': len(peaks),
            'cpu': (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime), 'ok': proc.returncode == 0,
            'sim_s': sim_s, 'steps': len(t), 'fresh': sum(fresh) / len(fresh) if fresh else float('nan'),
            'scenes': scenes[0] if c.view else float('nan')}


def held(run: Path, sim: Path) -> str:
    """Whether λ2 > 0 at every step of run from the first where sim's is, to the end (yes, or the steps it was not)."""
    a, b = records.read_csv(run / 'metrics.csv'), records.read_csv(sim / 'metrics.csv')
    n = min(len(a['fiedler']), len(b['fiedler']))
    first = next((k for k in range(n) if b['fiedler'][k] > 0), n)
    down = [k for k in range(first, n) if not a['fiedler'][k] > 0]
    return 'yes' if not down else f'no ({len(down)} steps)'


def main() -> None:
    if {'-h', '--help'} & set(sys.argv[1:]):
        print(__doc__)
        return
    configs = [parse(a) for a in sys.argv[1:] or DEFAULT_CONFIGS]
    # `up` forks its agents from a forkserver process that it does not wait for; as a subreaper we inherit it
    # when `up` ends, and waiting for it adds its agents' CPU time to ours (RUSAGE_CHILDREN).
    PR_SET_CHILD_SUBREAPER = 36
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)
    walls: dict[tuple[int, int, bool], float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        ref = Path(tmp) / 'sim'
        print('MAPs  per-process  sync          record  processes  sim s  wall s  start->first step s  real-time factor  '
              'peak RSS/process MB  peak PSS/process MB  CPU s  CPU ms/MAP-step  fresh cmds %  R_c %  (sim)  λ2      (sim)   equal to sim  '
              'λ2 > 0 where sim\'s  scenes received')
        for c in configs:
            maps, per, record, realtime, duration = c.maps, c.per, c.record, c.realtime, c.duration
            folder = Path(tmp) / f'up_{maps}_{per}_{record}_{realtime}_{c.rate}_{duration}_{c.view}'
            r = run(c, folder)
            if not realtime and duration is None:
                walls[maps, per, record] = r['wall'] - r['first']
            sim_folder = ref / f'{maps}_{duration}'
            if not sim_folder.exists():
                subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'sim', '--maps', str(maps), '--out',
                                str(sim_folder)] + (['--duration', str(duration)] if duration else []),
                               capture_output=True, check=True)
            same = 'n/a' if realtime else str(r['ok'] and (folder / 'trajectory.csv').read_bytes()
                                                == (sim_folder / 'trajectory.csv').read_bytes())
            rc, lam2 = final(folder / 'metrics.csv')
            rc_sim, lam2_sim = final(sim_folder / 'metrics.csv')
            print(f'{maps:4d}  {per:11d}  {f"realtime x{c.rate:<4g}" if realtime else "lockstep     "}  {"yes" if record else "no":>6}  '
                  f'{r["processes"]:9d}  {r["sim_s"]:5.0f}  {r["wall"]:6.1f}  {r["first"]:19.1f}  {r["rtf"]:16.2f}  '
                  f'{r["rss"]:19.0f}  {r["pss"]:19.0f}  {r["cpu"]:5.0f}  {1000 * r["cpu"] / (maps * r["steps"]):15.1f}  {r["fresh"]:12.0f}  {100 * rc:5.1f}  {100 * rc_sim:5.1f}  '
                  f'{lam2:.4f}  {lam2_sim:.4f}  {same}  {held(folder, sim_folder) if realtime else "n/a"}  '
                  f'{r["scenes"]:.0f}', flush=True)
        for (maps, per, record), wall in walls.items():
            if record and (maps, per, False) in walls:
                print(f'recording costs {maps}:{per} a factor {wall / walls[maps, per, False]:.3f} in wall time '
                      '(start-up excluded; target <= 1.10)')


if __name__ == '__main__':
    main()
