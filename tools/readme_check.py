"""Run every command of README.md's command blocks, as a new user would, and say which misbehave.

    ./uav-flock exec python tools/readme_check.py [--clone DIR] [--skip WORD ...]

In a fresh clone of the repository (DIR, default: this checkout), each line of each ```bash block runs in
order from the clone's top folder. A command passes when it exits 0, prints no traceback and no
below-the-floor note. Two kinds are handled as a user would: `topics`, `echo` and `kill` of a run are
given a live run (the `up` that writes that folder is started in the background and waited for), and a
command that serves until Ctrl-C (`echo` without --once, `view`) gets a SIGINT after a while. Left out:
`make test` (the suite, which CI runs), and the native-ROS and Docker blocks (no ROS or Docker here).
Takes about three quarters of an hour on two cores (`paper` alone about 17 minutes; `--skip paper` leaves it out).
"""
from __future__ import annotations

import argparse
import os
import re
import shlex
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

FLOOR_NOTE = 'below the floor'
SERVE_S = 8.0  # how long a command that serves until Ctrl-C is left to serve
LIVE_RUN_WAIT_S = 300.0  # for a background `up` to print its first progress line
LIVE = ('topics', 'echo', 'kill')  # commands that look into a run while it flies
NOT_HERE = ('make test', 'docker ', 'source ', 'cd ros2_ws', 'export ')


@dataclass
class Outcome:
    line: str
    code: Optional[int]
    seconds: float
    why: str = ''

    @property
    def ok(self) -> bool:
        return self.code == 0 and not self.why


def commands(readme: str) -> list[str]:
    """The command lines of every ```bash block, continuation lines joined, comments kept for the record."""
    lines: list[str] = []
    for block in re.findall(r'```bash\n(.*?)```', readme, flags=re.S):
        joined = block.replace('\\\n', ' ')
        for raw in joined.splitlines():
            words = shlex.split(raw, comments=True)
            if words:
                lines.append(shlex.join(words))
    return lines


def option(words: list[str], name: str) -> Optional[str]:
    return words[words.index(name) + 1] if name in words[:-1] else None


def serves_until_interrupted(words: list[str]) -> bool:
    command = words[1] if len(words) > 1 else ''
    return (command == 'echo' and '--once' not in words) or command == 'view'


def judge(line: str, code: Optional[int], out: str, seconds: float) -> Outcome:
    why = []
    if 'Traceback' in out:
        why.append('a traceback')
    if FLOOR_NOTE in out:
        why.append('a below-the-floor note')
    return Outcome(line, code, seconds, ', '.join(why))


def run_line(line: str, cwd: Path) -> Outcome:
    words = shlex.split(line)
    start = time.monotonic()
    # No shell in front, as a user types it: Ctrl-C and the exit code are the command's own.
    proc = subprocess.Popen(words, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    why = ''
    if serves_until_interrupted(words):
        try:
            out, _ = proc.communicate(timeout=SERVE_S)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C: the terminal signals the whole foreground group
            try:
                out, _ = proc.communicate(timeout=60)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                out, _ = proc.communicate()
                why = 'still running 60 s after Ctrl-C'
    else:
        out, _ = proc.communicate()
    print(out, end='', flush=True)
    outcome = judge(line, proc.returncode, out, time.monotonic() - start)
    outcome.why = ', '.join(w for w in (outcome.why, why) if w)
    return outcome


class LiveRun:
    """An `up` in the background, for the commands that look into it while it flies."""

    def __init__(self, line: str, cwd: Path) -> None:
        self.line, self.start = line, time.monotonic()
        self.log = cwd / f'.readme-check-{abs(hash(line))}.log'
        self.file = open(self.log, 'w+')
        self.proc = subprocess.Popen(shlex.split(line), cwd=cwd, stdout=self.file, stderr=subprocess.STDOUT, text=True)
        deadline = time.monotonic() + LIVE_RUN_WAIT_S
        while time.monotonic() < deadline and self.proc.poll() is None and 't = ' not in self.log.read_text():
            time.sleep(0.5)

    def finish(self) -> Outcome:
        self.proc.wait()
        out = self.log.read_text()
        self.file.close()
        self.log.unlink()
        print(out, end='', flush=True)
        return judge(self.line, self.proc.returncode, out, time.monotonic() - self.start)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--clone', type=Path, default=Path(__file__).resolve().parents[1],
                        help='the repository copy to run in (default: this checkout)')
    parser.add_argument('--skip', nargs='*', default=[], help='leave out lines that hold any of these words')
    args = parser.parse_args()
    readme = (args.clone / 'README.md').read_text()
    lines = [line for line in commands(readme)
             if not any(line.startswith(n) or f' {n}' in f' {line}' for n in NOT_HERE)
             and not any(word in line for word in args.skip)]
    looked_into = {option(shlex.split(line), '--run') for line in lines
                   if len(shlex.split(line)) > 1 and shlex.split(line)[1] in LIVE}
    results: list[Outcome] = []
    live: dict[str, LiveRun] = {}
    try:
        for line in lines:
            words = shlex.split(line)
            print(f'\n$ {line}', flush=True)
            out_folder = option(words, '--out')
            if len(words) > 1 and words[1] == 'up' and out_folder in looked_into:
                live[out_folder] = LiveRun(line, args.clone)
                continue
            results.append(run_line(line, args.clone))
            run = option(words, '--run')
            if run in live and not any(option(shlex.split(later), '--run') == run
                                       for later in lines[lines.index(line) + 1:]):
                results.append(live.pop(run).finish())
    except KeyboardInterrupt:
        print('readme_check: interrupted; what ran so far:', file=sys.stderr)
    finally:
        for run in live.values():
            results.append(run.finish())
    print('\n| exit | s | command | what went wrong |\n|---|---|---|---|')
    for r in results:
        print(f'| {r.code} | {r.seconds:.0f} | `{r.line}` | {r.why or ("" if r.ok else "non-zero exit")} |')
    bad = [r for r in results if not r.ok]
    print(f'\n{len(results) - len(bad)} passed, {len(bad)} failed')
    return 1 if bad else 0


if __name__ == '__main__':
    sys.exit(main())
