"""Distributed runs of the paper scenario: wall time, real-time factor, start-up, memory and CPU.

Run: ./uav-flock exec python benchmarks/bench_runtime.py [MAPS:PER_PROCESS[:record] ...]
(default 90:10 90:45). With ':record' the run also writes its bag (`up --record`); when a configuration
is given with and without it, the cost of recording is printed as the ratio of the two wall times.
Each configuration is also checked against the batch simulator (trajectory equal to the byte).
"""
from __future__ import annotations

import resource
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from uav_flock_tools.launcher import read_pid_table


def peak_rss_mb(pids: set[int]) -> dict[int, float]:
    out = {}
    for pid in pids:
        try:
            for line in Path(f'/proc/{pid}/status').read_text().splitlines():
                if line.startswith('VmHWM:'):
                    out[pid] = int(line.split()[1]) / 1024
        except OSError:
            pass
    return out


def run(maps: int, per_process: int, folder: Path, record: bool) -> dict[str, float]:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, '-m', 'uav_flock_tools.cli', 'up', '--maps', str(maps),
                             '--agents-per-process', str(per_process), '--out', str(folder)]
                            + (['--record'] if record else []),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    first_step = None
    peaks: dict[int, float] = {}

    def sample() -> None:
        while proc.poll() is None:
            if (folder / 'pids.json').exists():
                try:
                    peaks.update(peak_rss_mb(set(read_pid_table(folder).values())))
                except ValueError:
                    pass
            time.sleep(1.0)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    assert proc.stdout is not None
    for line in proc.stdout:
        if first_step is None and line.startswith('t =   0.0 s'):
            first_step = time.monotonic() - t0
    proc.wait()
    wall = time.monotonic() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    sim_s = float((folder / 'metrics.csv').read_text().strip().splitlines()[-1].split(',')[1])
    return {'wall': wall, 'first': first_step or float('nan'), 'rtf': sim_s / (wall - (first_step or 0)),
            'rss': max(peaks.values()) if peaks else float('nan'), 'processes': len(peaks),
            'cpu': (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime), 'ok': proc.returncode == 0}


def main() -> None:
    configs = [(int(a.split(':')[0]), int(a.split(':')[1]), a.endswith(':record')) for a in sys.argv[1:]] \
        or [(90, 10, False), (90, 45, False)]
    walls: dict[tuple[int, int, bool], float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        ref = Path(tmp) / 'sim'
        print('MAPs  per-process  record  processes  wall s  start->first step s  real-time factor  '
              'peak RSS/process MB  CPU s  equal to sim')
        for maps, per, record in configs:
            folder = Path(tmp) / f'up_{maps}_{per}_{record}'
            r = run(maps, per, folder, record)
            walls[maps, per, record] = r['wall'] - r['first']
            subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', 'sim', '--maps', str(maps),
                            '--out', str(ref / str(maps))], capture_output=True, check=True)
            same = (folder / 'trajectory.csv').read_bytes() == (ref / str(maps) / 'trajectory.csv').read_bytes()
            print(f'{maps:4d}  {per:11d}  {"yes" if record else "no":>6}  {r["processes"]:9d}  {r["wall"]:6.1f}  '
                  f'{r["first"]:19.1f}  {r["rtf"]:16.2f}  {r["rss"]:19.0f}  {r["cpu"]:5.0f}  {same and r["ok"]}', flush=True)
        for (maps, per, record), wall in walls.items():
            if record and (maps, per, False) in walls:
                print(f'recording costs {maps}:{per} a factor {wall / walls[maps, per, False]:.3f} in wall time '
                      '(start-up excluded; target <= 1.10)')


if __name__ == '__main__':
    main()
