"""Process checks and node parameter files, shared by the world node, the launcher, replay and tests."""
from __future__ import annotations

import signal
from pathlib import Path
from typing import Any

import yaml


# In a run folder, beside pids.json: one empty file per MAP that `uav-flock kill` ended inside a process
# that lives on for its other MAPs (world_sim drops those MAPs as it drops one whose process is gone).
CRASH_DIR = 'crash'
# The signal by which an agent process whose run ended leaves when its DDS teardown holds the GIL (so no Python
# timer can end it): the process that started it takes that end as a clean one (agent_node.leave_after, join.py).
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
