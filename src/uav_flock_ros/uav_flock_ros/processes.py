"""Process checks, node parameter files and the last word of a node process, shared by the world node, the
agent node, the launcher, replay and tests."""
from __future__ import annotations

import faulthandler
import os
import signal
import sys
import threading
from pathlib import Path
from typing import Any

import yaml


# In a run folder, beside pids.json: one empty file per MAP that `uav-flock kill` ended inside a process
# that lives on for its other MAPs (world_sim drops those MAPs as it drops one whose process is gone).
CRASH_DIR = 'crash'
# How long a node's DDS participant may take to go once its run ended and its records are written, before the
# process leaves without it: a secured run's agents over three hosts all said the run was finished and one process
# of a joining host was still there 60 s later; a run whose recorder was SIGKILLed once did not end within 120 s
# in CI (world_sim's teardown the suspect).
TEARDOWN_S = 15.0
# The signal by which a node process whose run ended well leaves when its DDS teardown holds the GIL (so no Python
# timer can end it): the process that started it takes that end as a clean one (leave_after; join.py, launcher.py).
TEARDOWN_SIGNAL = signal.SIGALRM
LINKS_LOG_DIR = 'links'  # realtime under a channel: map_<id>.csv, each neighbour state that arrived and its fate


def write_params(path: Path, values: dict[str, Any]) -> Path:
    """A ros__parameters file that applies to every node of the process (`--ros-args --params-file`)."""
    path.write_text(yaml.safe_dump({'/**': {'ros__parameters': values}}, sort_keys=False))
    return path


def process_alive(pid: int) -> bool:
    """A process that exists and is not a zombie (killed but not yet reaped)."""
    try:
        with open(f'/proc/{pid}/stat') as f:
            return f.read().rsplit(')', 1)[1].split()[0] != 'Z'
    except (OSError, IndexError):
        return False


def leave_after(code: int, who: str, seconds: float = TEARDOWN_S) -> None:
    """End this process with code if it is still here after seconds (a daemon timer), its records written: a
    DDS teardown has held agents over 120 s. If even that timer cannot run (a teardown in C holding the GIL),
    the threads' tracebacks go into the log and, for a run that ended well, the kernel ends the process by
    TEARDOWN_SIGNAL (both need no GIL; one that ended badly leaves with 1 by faulthandler)."""
    faulthandler.dump_traceback_later(seconds + 5.0, exit=code != 0)
    if code == 0:
        signal.signal(TEARDOWN_SIGNAL, signal.SIG_DFL)
        signal.alarm(int(seconds) + 10)

    def leave() -> None:
        print(f'{who}: the DDS participant took over {seconds:.0f} s to go: leaving without it', flush=True)
        sys.stderr.flush()
        os._exit(code)

    timer = threading.Timer(seconds, leave)
    timer.daemon = True
    timer.start()
