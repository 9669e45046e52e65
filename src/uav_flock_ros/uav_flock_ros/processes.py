"""Process checks the world node and the command line share."""
from __future__ import annotations


def process_alive(pid: int) -> bool:
    """A process that exists and is not a zombie (killed but not yet reaped)."""
    try:
        with open(f'/proc/{pid}/stat') as f:
            return f.read().rsplit(')', 1)[1].split()[0] != 'Z'
    except (OSError, IndexError):
        return False
