"""A job whose stdout closes (`| head -1`) goes on to the end: its records are its files, not its stdout."""
from __future__ import annotations

import shlex
import subprocess
import sys
from pathlib import Path

from world_sim.core.records import read_csv


def piped(args: str, env: dict[str, str] | None = None, merged: bool = False, lines: int = 1) -> tuple[int, str, str]:
    """The command's exit code, what `head` kept and the command's stderr, the pipe closed after `lines` lines;
    merged: stderr into the same pipe (`2>&1 | head`), where the progress bar and the notes go."""
    command = f'{shlex.quote(sys.executable)} -m uav_flock_tools.cli {args}' + (' 2>&1' if merged else '')
    done = subprocess.run(['bash', '-c', f'{command} | head -{lines}; exit ${{PIPESTATUS[0]}}'],
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


def test_a_sim_whose_stderr_closes_flies_to_the_end_and_writes_its_folder(tmp_path: Path) -> None:
    """`sim ... 2>&1 | head -1`: the vehicle's line takes the one line, then the floor note and the progress bar
    write into the closed pipe. Each seed's folder is written in full."""
    out = tmp_path / 'p'
    code, kept, said = piped(f'sim --maps 30 --duration 3 --seed 0,1 --out {out}', merged=True)
    assert code == 0 and 'Traceback' not in kept + said, kept + said
    assert len(kept.splitlines()) == 1 and kept.startswith('vehicle:'), kept
    for seed in (0, 1):
        steps = read_csv(out / f'maps30_seed{seed}' / 'metrics.csv')['step']
        assert steps.astype(int).tolist() == list(range(31)), f'seed {seed}: {len(steps)} of 31 steps'
    assert (out / 'summary.csv').exists() and (out / 'coverage.png').exists(), sorted(p.name for p in out.iterdir())


def test_a_study_whose_stderr_closes_computes_every_run(tmp_path: Path) -> None:
    """`study ... 2>&1 | head -3`: the progress lines go into a closed pipe from the third on; every run of
    the grid is in results.parquet all the same, and the exit code says the study succeeded."""
    import pandas as pd
    spec = tmp_path / 'tiny.yaml'
    spec.write_text('layouts: {count: 2, clusters: [3, 3], seed: 0}\nseeds: [0, 1]\nkinds: [static]\n'
                    'duration: 5\nvariants: {base: {}}\n')
    out = tmp_path / 's'
    code, kept, said = piped(f'study {spec} --out {out} --workers 1', merged=True, lines=2)
    assert code == 0 and 'Traceback' not in kept + said, kept + said
    assert len(kept.splitlines()) == 2, kept
    rows = pd.read_parquet(out / 'results.parquet')
    assert len(rows) == 4 and rows['error'].isna().all(), rows


def test_a_sim_started_with_its_standard_streams_closed_writes_every_folder(tmp_path: Path) -> None:
    """`./uav-flock sim ... >&- 2>&-` (and each stream alone): bash leaves its own script on the first free
    descriptor, 2, read-only; the job runs as if both went to /dev/null, every folder written, exit 0."""
    root = Path(__file__).resolve().parents[2]
    for closed in ('>&-', '2>&-', '<&- >&- 2>&-'):
        out = tmp_path / f'closed{len(closed)}'
        command = f'{shlex.quote(str(root / "uav-flock"))} sim --maps 30 --duration 3 --seed 0,1 --out {out} {closed}'
        done = subprocess.run(['bash', '-c', command], capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, f'{closed}: exit {done.returncode}'
        for seed in (0, 1):
            steps = read_csv(out / f'maps30_seed{seed}' / 'metrics.csv')['step']
            assert steps.astype(int).tolist() == list(range(31)), f'{closed}, seed {seed}: {len(steps)} of 31 steps'
        assert (out / 'summary.csv').exists(), f'{closed}: {sorted(p.name for p in out.iterdir())}'
