"""Shared-memory files that participants of a run left behind: removed when the run ends."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Optional

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
