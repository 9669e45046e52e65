"""The run records every runner writes: metrics.csv and trajectory.csv, one column set for all."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import numpy as np

from .physics import Users

USERS_FILE = 'users.npz'        # what world_sim leaves besides the two CSV files
FAILURES_FILE = 'failures.json'
METRICS_COLUMNS = ('step', 't', 'coverage_ratio', 'fiedler', 'alive', 'components', 'mode0', 'mode1', 'mode2')
TRAJECTORY_COLUMNS = ('step', 't', 'id', 'x', 'y', 'z', 'vx', 'vy', 'vz', 'mode', 'goal', 'user_count')
_METRICS_FMT = ('%d', '%.10g', '%.10g', '%.10g', '%d', '%d', '%d', '%d', '%d')
_TRAJECTORY_FMT = ('%d', '%.10g', '%d') + ('%.17g',) * 6 + ('%d', '%d', '%d')


def write_csv(path: Path, columns: tuple[str, ...], rows: np.ndarray, fmt: tuple[str, ...]) -> None:
    rows = np.asarray(rows, dtype=float).reshape(-1, len(columns))
    np.savetxt(path, rows, fmt=list(fmt), delimiter=',', header=','.join(columns), comments='')


def write_metrics(path: Path, rows: np.ndarray) -> None:
    write_csv(path, METRICS_COLUMNS, rows, _METRICS_FMT)


def write_trajectory(path: Path, rows: np.ndarray) -> None:
    write_csv(path, TRAJECTORY_COLUMNS, rows, _TRAJECTORY_FMT)


def columns(rows: np.ndarray, names: tuple[str, ...] = TRAJECTORY_COLUMNS) -> dict[str, np.ndarray]:
    """A record's rows as named columns (the trajectory's by default)."""
    return {c: rows[:, i] for i, c in enumerate(names)}


def rows(cols: dict[str, np.ndarray], names: tuple[str, ...]) -> np.ndarray:
    """Named columns back into rows in the record's column order."""
    return np.column_stack([cols[c] for c in names]).reshape(-1, len(names))


def read_csv(path: Path) -> dict[str, np.ndarray]:
    """Columns of a metrics or trajectory file by name."""
    data = np.genfromtxt(path, delimiter=',', names=True, dtype=float)
    data = np.atleast_1d(data)
    return {name: data[name] for name in data.dtype.names}


def write_users(path: Path, users: Users) -> None:
    """The run's MSDs (users.npz), so that nothing after the run has to draw them again from the seed."""
    radii = np.full(len(users.centroids), np.nan) if users.radii is None else users.radii
    np.savez(path, xyz=users.xyz, cluster=users.cluster, centroids=users.centroids, radii=radii)


def read_users(path: Path) -> Users:
    with np.load(path) as f:
        radii = f['radii']
        return Users(f['xyz'], f['cluster'].astype(np.intp), f['centroids'], None if np.isnan(radii).any() else radii)


def write_failures(path: Path, failed: np.ndarray, fail_step: Optional[int]) -> None:
    """The MAPs that left the run (failed by the schedule or killed) and the scheduled failure's step."""
    path.write_text(json.dumps({'failed': [int(i) for i in failed], 'fail_step': fail_step}))


def read_failures(path: Path) -> tuple[np.ndarray, Optional[int]]:
    doc = json.loads(path.read_text())
    return np.asarray(doc['failed'], dtype=np.intp), doc['fail_step']
