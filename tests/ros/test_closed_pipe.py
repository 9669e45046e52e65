"""A job whose stdout closes (`| head -1`) goes on to the end: its records are its files, not its stdout."""
from __future__ import annotations

import shlex
import subprocess
import sys
from pathlib import Path

from world_sim.core.records import read_csv


def piped(args: str, env: dict[str, str] | None = None) -> tuple[int, str, str]:
    """The command's exit code, what `head -1` kept and the command's stderr, the pipe closed after one line."""
    command = f'{shlex.quote(sys.executable)} -m uav_flock_tools.cli {args}'
    done = subprocess.run(['bash', '-c', f'{command} | head -1; exit ${{PIPESTATUS[0]}}'],
                          capture_output=True, text=True, timeout=600, env=env)
    return done.returncode, done.stdout, done.stderr


def test_a_run_piped_into_head_flies_every_step_and_keeps_every_record(tmp_path: Path,
                                                                        ros_env: dict[str, str]) -> None:
    out = tmp_path / 'p'
    code, kept, said = piped(f'up --maps 6 --duration 4 --record --out {out}', ros_env)
    assert code == 0 and 'Traceback' not in said, said
    assert len(kept.splitlines()) == 1, kept
    steps = read_csv(out / 'metrics.csv')['step']
    assert steps.astype(int).tolist() == list(range(41)), f'{len(steps)} of 41 steps in metrics.csv'
    for name in ('coverage.png', 'fiedler.png', 'modes.png', 'formation.png', 'formation.gif', 'trajectory.npz',
                 'bag/metadata.yaml'):
        assert (out / name).exists(), f'{name} missing after the pipe closed'


def test_a_layout_set_piped_into_head_writes_every_layout_and_its_table(tmp_path: Path) -> None:
    out = tmp_path / 'l'
    code, kept, said = piped(f'layouts --count 5 --out {out}')
    assert code == 0 and 'Traceback' not in said, said
    assert len(kept.splitlines()) == 1, kept
    assert sorted(p.name for p in out.iterdir()) == [f'layout-{i:03d}.yaml' for i in range(5)] + ['layouts.csv']
    assert all(len(column) == 5 for column in read_csv(out / 'layouts.csv').values())
