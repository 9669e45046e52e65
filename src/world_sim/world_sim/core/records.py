"""The run records every runner writes: metrics.csv and trajectory.csv, one column set for all."""
from __future__ import annotations

from pathlib import Path

import numpy as np

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


def read_csv(path: Path) -> dict[str, np.ndarray]:
    """Columns of a metrics or trajectory file by name."""
    data = np.genfromtxt(path, delimiter=',', names=True, dtype=float)
    data = np.atleast_1d(data)
    return {name: data[name] for name in data.dtype.names}
