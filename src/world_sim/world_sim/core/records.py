"""The run records every runner writes: metrics.csv and trajectory.csv, one column set for all, and the
trajectory again by column (trajectory.npz), what a reader of a large run loads in a blink."""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from .physics import Users

USERS_FILE = 'users.npz'        # what world_sim leaves besides the two CSV files
FAILURES_FILE = 'failures.json'
METRICS_COLUMNS = ('step', 't', 'coverage_ratio', 'fiedler', 'alive', 'components', 'mode0', 'mode1', 'mode2')
TRAJECTORY_COLUMNS = ('step', 't', 'id', 'x', 'y', 'z', 'vx', 'vy', 'vz', 'mode', 'goal', 'user_count')
_METRICS_FMT = ('%d', '%.10g', '%.10g', '%.10g', '%d', '%d', '%d', '%d', '%d')
_TRAJECTORY_FMT = ('%d', '%.10g', '%d') + ('%.17g',) * 6 + ('%d', '%d', '%d')
# A multirotor's run (world_sim/core/vehicle.py) adds to metrics.csv the least distance between two MAPs (m),
# the formation's mean propulsion power (W), the energy it drew before the step (J), and under the safety filter
# the MAPs whose filter relaxed a protected link and those a protected link held back (safety.RELAXED, HELD; 0
# under the rules); to the trajectory, where
# each MAP believed it was (its GNSS estimate, m) beside x, y, z, which stay the truth.
VEHICLE_COLUMNS = ('min_distance', 'power', 'energy', 'relaxed', 'held')
_VEHICLE_FMT = ('%.10g',) * 3 + ('%d',) * 2
ESTIMATE_COLUMNS = ('x_est', 'y_est', 'z_est')
TRAJECTORY_NPZ = 'trajectory.npz'
# trajectory.npz's column types: the CSV's values exactly (t as computed, not printed to 10 digits)
_TRAJECTORY_TYPES = (np.int32, np.float64, np.int32) + (np.float64,) * 6 + (np.int8, np.int16, np.int32)


def write_csv(path: Path, columns: tuple[str, ...], rows: np.ndarray, fmt: tuple[str, ...]) -> None:
    rows = np.asarray(rows, dtype=float).reshape(-1, len(columns))
    np.savetxt(path, rows, fmt=list(fmt), delimiter=',', header=','.join(columns), comments='')


def metrics_columns(scenario: Any) -> tuple[str, ...]:
    """metrics.csv's columns for a run of this scenario: LINK_COLUMNS under a channel (hearing.py), then
    VEHICLE_COLUMNS on a multirotor."""
    from .hearing import LINK_COLUMNS
    return (METRICS_COLUMNS + (() if scenario.links.perfect else LINK_COLUMNS)
            + (() if scenario.vehicle.ideal else VEHICLE_COLUMNS))


def has_links(metrics: np.ndarray) -> bool:
    """Whether metrics rows (or one row) carry hearing.LINK_COLUMNS after METRICS_COLUMNS: a run under a channel."""
    from .hearing import LINK_COLUMNS
    extra = np.shape(metrics)[-1] - len(METRICS_COLUMNS)
    return extra in (len(LINK_COLUMNS), len(LINK_COLUMNS) + len(VEHICLE_COLUMNS))


def vehicle_column(metrics: np.ndarray, name: str) -> Optional[np.ndarray]:
    """A multirotor's VEHICLE_COLUMNS column of metrics rows (they come last); None on the paper's vehicle."""
    from .hearing import LINK_COLUMNS
    extra = np.shape(metrics)[-1] - len(METRICS_COLUMNS)
    if extra not in (len(VEHICLE_COLUMNS), len(LINK_COLUMNS) + len(VEHICLE_COLUMNS)):
        return None
    return np.asarray(metrics)[..., np.shape(metrics)[-1] - len(VEHICLE_COLUMNS) + VEHICLE_COLUMNS.index(name)]


def write_metrics(path: Path, rows: np.ndarray) -> None:
    """METRICS_COLUMNS, then those of a channel and a multirotor as metrics_columns says (told by the width)."""
    from .hearing import LINK_COLUMNS, LINK_FMT
    rows = np.asarray(rows, dtype=float)
    width = rows.shape[1] if rows.ndim == 2 else len(METRICS_COLUMNS)
    columns, fmt = METRICS_COLUMNS, _METRICS_FMT
    if width - len(METRICS_COLUMNS) in (len(LINK_COLUMNS), len(LINK_COLUMNS) + len(VEHICLE_COLUMNS)):
        columns, fmt = columns + LINK_COLUMNS, fmt + LINK_FMT
    if width - len(columns) == len(VEHICLE_COLUMNS):
        columns, fmt = columns + VEHICLE_COLUMNS, fmt + _VEHICLE_FMT
    write_csv(path, columns, rows, fmt)


def trajectory_columns(rows: np.ndarray) -> tuple[str, ...]:
    """TRAJECTORY_COLUMNS, and ESTIMATE_COLUMNS after them in a multirotor's run."""
    wide = np.ndim(rows) == 2 and np.shape(rows)[1] == len(TRAJECTORY_COLUMNS) + len(ESTIMATE_COLUMNS)
    return TRAJECTORY_COLUMNS + (ESTIMATE_COLUMNS if wide else ())


def write_trajectory(path: Path, rows: np.ndarray) -> None:
    """trajectory.csv at path, and beside it trajectory.npz: one typed array per column (np.load(...)['x'])."""
    names = trajectory_columns(rows)
    extra = len(names) - len(TRAJECTORY_COLUMNS)
    write_csv(path, names, rows, _TRAJECTORY_FMT + ('%.17g',) * extra)
    rows = np.asarray(rows, dtype=float).reshape(-1, len(names))
    types = _TRAJECTORY_TYPES + (np.float64,) * extra
    np.savez(path.with_name(TRAJECTORY_NPZ), **{c: rows[:, i].astype(t) for i, (c, t) in enumerate(zip(names, types))})


def read_trajectory(folder: Path) -> dict[str, np.ndarray]:
    """A run's trajectory by column: from trajectory.npz, or trajectory.csv in a run recorded before it."""
    if (folder / TRAJECTORY_NPZ).exists():
        with np.load(folder / TRAJECTORY_NPZ) as f:
            return {c: f[c].astype(float) for c in TRAJECTORY_COLUMNS + ESTIMATE_COLUMNS if c in f.files}
    return read_csv(folder / 'trajectory.csv')


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


@dataclass
class Motion:
    """Where the MSDs were at every survey step of a run whose users move."""

    steps: np.ndarray      # (S,) step k of each record
    xy: np.ndarray         # (S, M, 2) every drawn MSD's position (m), float32
    present: np.ndarray    # (S, M) whether it was there
    label: np.ndarray      # (S, M) its cluster as the MAPs knew it (-1: none)

    def at(self, step: int) -> tuple[np.ndarray, np.ndarray]:
        """(xy, cluster) of the MSDs present at the last record at or before step."""
        i = max(int(np.searchsorted(self.steps, step, side='right')) - 1, 0)
        return self.xy[i][self.present[i]].astype(float), self.label[i][self.present[i]].astype(np.intp)


def write_users(path: Path, users: Users, motion: Optional[Motion] = None) -> None:
    """The run's MSDs (users.npz), so that nothing after the run has to draw them again from the seed;
    with their motion when they moved."""
    radii = np.full(len(users.centroids), np.nan) if users.radii is None else users.radii
    extra = {} if motion is None else {f'motion_{k}': v for k, v in vars(motion).items()}
    np.savez(path, xyz=users.xyz, cluster=users.cluster, centroids=users.centroids, radii=radii, **extra)


def read_users(path: Path) -> Users:
    with np.load(path) as f:
        radii = f['radii']
        return Users(f['xyz'], f['cluster'].astype(np.intp), f['centroids'], None if np.isnan(radii).any() else radii)


def read_motion(path: Path) -> Optional[Motion]:
    with np.load(path) as f:
        if 'motion_steps' not in f:
            return None
        return Motion(f['motion_steps'], f['motion_xy'], f['motion_present'], f['motion_label'])


def write_failures(path: Path, failed: np.ndarray, fail_step: Optional[int],
                   events: Sequence[tuple[int, list[int], str]] = ()) -> None:
    """The MAPs that left the run (failed by the schedule or killed), the scheduled failure's step, and each
    drop as it came: step, ids and cause ('scheduled', or 'killed': its process or host gone)."""
    path.write_text(json.dumps({'failed': [int(i) for i in failed], 'fail_step': fail_step,
                                'events': [{'step': int(k), 'ids': [int(i) for i in ids], 'cause': cause}
                                           for k, ids, cause in events]}))


def read_failures(path: Path) -> tuple[np.ndarray, Optional[int], list[tuple[int, list[int], str]]]:
    doc = json.loads(path.read_text())
    events = [(int(e['step']), [int(i) for i in e['ids']], str(e['cause'])) for e in doc.get('events', [])]
    return np.asarray(doc['failed'], dtype=np.intp), doc['fail_step'], events
