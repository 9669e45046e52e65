"""Running the command line from tests: the CLI as a child process, `up` in the background."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path


def cli(*args: str, env: dict[str, str] | None = None, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, '-m', 'uav_flock_tools.cli', *args], capture_output=True, text=True,
                          timeout=timeout, env=env)


def up(*args: str, env: dict[str, str] | None = None) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, '-m', 'uav_flock_tools.cli', 'up', *args], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=env)


def helper(module: str, *args: str, env: dict[str, str]) -> subprocess.Popen[str]:
    """A helper process (tests/helpers) once it has made its endpoints and printed 'ready'.

    A run of a few seconds may end before a helper that is still importing rclpy on a loaded machine has
    met its MAPs; started first, the helper is met by every MAP while the MAPs discover each other.
    """
    proc = subprocess.Popen([sys.executable, '-m', f'helpers.{module}', *args], cwd=Path(__file__).resolve().parents[1],
                            env=env, stdout=subprocess.PIPE, text=True)
    try:
        wait_for_line(proc, 'ready', 60)
    except AssertionError:
        proc.kill()
        proc.wait()
        raise
    return proc


def dead(pid: int) -> bool:
    """Gone or a zombie: world_sim's own test of a MAP's process."""
    from uav_flock_ros.processes import process_alive
    return not process_alive(pid)


def wait_for_line(proc: subprocess.Popen[str], needle: str, timeout: float) -> list[str]:
    seen: list[str] = []
    deadline = time.monotonic() + timeout
    assert proc.stdout is not None
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        seen.append(line)
        if needle in line:
            return seen
    raise AssertionError(f'{needle!r} not printed within {timeout} s:\n' + ''.join(seen))


def ended(proc: subprocess.Popen[str], timeout: float, run: Path) -> str:
    """The rest of what `up` prints until it ends; if it does not end in time, a failure that says where it was
    (its last lines, the processes still there, the last lines of each log) instead of a bare timeout."""
    try:
        return proc.communicate(timeout=timeout)[0]
    except subprocess.TimeoutExpired as exc:
        said = exc.output.decode(errors='replace') if isinstance(exc.output, bytes) else (exc.output or '')
        left = [f'{pid}: {Path(f"/proc/{pid}/cmdline").read_text(errors="replace").replace(chr(0), " ")[:160]}'
                for pid in descendants(proc.pid)]
        logs = [f'--- {log.name}\n' + '\n'.join(log.read_text(errors='replace').splitlines()[-15:])
                for log in sorted((run / 'logs').glob('*.log'))]
        raise AssertionError(f'up did not end within {timeout} s; it printed last:\n'
                             + '\n'.join(said.splitlines()[-10:]) + '\nstill running:\n' + '\n'.join(left)
                             + '\n' + '\n'.join(logs)) from None


def descendants(pid: int) -> list[int]:
    """Every process under pid, children first (from /proc; gone ones skipped)."""
    try:
        kids = [int(c) for t in Path(f'/proc/{pid}/task').iterdir() for c in (t / 'children').read_text().split()]
    except OSError:
        return []
    return kids + [d for k in kids for d in descendants(k)]


def dropped_ids(text: str, cause: str = 'killed') -> list[int]:
    """The MAP ids of world_sim's 'dropped MAPs [..] (cause)' lines."""
    return sorted(int(i) for line in text.splitlines() if f'({cause})' in line
                  for i in line.split('[')[1].split(']')[0].split(','))


def kill_during(proc: subprocess.Popen[str], run: str, ids: str, after: str) -> tuple[str, str]:
    """Kill MAP ids of a running `up` once it prints `after`; (what it printed until the drops, all the rest)."""
    try:
        wait_for_line(proc, after, 120)
        killed = cli('kill', '--run', run, '--ids', ids)
        assert killed.returncode == 0 and f"MAPs [{ids.replace(',', ', ')}]" in killed.stdout, \
            killed.stdout + killed.stderr
        seen = ''.join(wait_for_line(proc, '(killed)', 60))
        if len(dropped_ids(seen)) < len(ids.split(',')):  # the deaths may be noticed in two liveness checks
            seen += ''.join(wait_for_line(proc, '(killed)', 60))
        rest, _ = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
    return seen, rest


def shm_entries() -> set[str]:
    """Fast DDS files in /dev/shm: participants' segments and their locks, port files and their semaphores."""
    shm = Path('/dev/shm')
    return {p.name for p in shm.iterdir() if 'fastrtps' in p.name or 'fastdds' in p.name} if shm.is_dir() else set()
