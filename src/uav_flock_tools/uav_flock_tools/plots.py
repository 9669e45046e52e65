"""Figures of a run: coverage and Fiedler over time, mode counts, formation snapshots and animation."""
from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Callable, Sequence, Union

import matplotlib

matplotlib.use('Agg')
matplotlib.rcParams['agg.path.chunksize'] = 10000  # links_within's one path of thousands of links
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from world_sim.core import records  # noqa: E402
from world_sim.core.physics import label_centroids, neighbour_pairs  # noqa: E402

# The MSDs (xy, cluster id) at a time, for runs whose users move.
# An event to mark on a time axis: a time (a failure) or (time, what happened).
Event = Union[float, tuple[float, str]]
UsersAt = Callable[[float], tuple[np.ndarray, np.ndarray]]
MODE_COLOURS = ('tab:blue', 'tab:orange', 'tab:green')
# M0 is also a server at a cluster still under r0 coverage (docs/allocation.md): it stays dynamic there.
MODE_NAMES = ('M0 dynamic (cluster not yet served)', 'M1 connectivity', 'M2 static')


def save(fig: plt.Figure, path: Path) -> Path:
    """Lay out, write as PNG and free the figure."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def finish(ax: plt.Axes, xlabel: str, ylabel: str, title: str, events: Sequence[Event] = ()) -> None:
    """Event marks (a bare time is a failure), axis labels with units, title, grid, and a legend when there
    is more than one thing to tell apart."""
    for e in events:
        t, what = e if isinstance(e, tuple) else (e, 'failure')
        ax.axvline(t, color='grey', ls='--', lw=1, label=f'{what} at t = {t:g} s')
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    if len(ax.get_legend_handles_labels()[1]) > 1:
        ax.legend(loc='best', fontsize=8)


FIEDLER_LINEAR_BELOW = 1e-3  # the symlog axis is linear below this, so lambda2 = 0 sits on the axis
FIEDLER_LABEL = f'Fiedler value λ2 (no unit; log scale above {FIEDLER_LINEAR_BELOW:g})'


def fiedler_axis(ax: plt.Axes, t: np.ndarray | None = None, fiedler: np.ndarray | None = None) -> None:
    """A symlog axis for lambda2, where 0.02 stands well clear of 0, with 0 marked as disconnected; given
    one run's series, its disconnected spans are shaded."""
    ax.set_yscale('symlog', linthresh=FIEDLER_LINEAR_BELOW)
    ax.set_ylim(bottom=0.0)
    ax.axhline(0.0, color='k', lw=1.2, label='λ2 = 0: disconnected')
    if t is not None and fiedler is not None and len(t):
        off = np.asarray(fiedler) <= 0
        edges = np.flatnonzero(np.diff(np.r_[0, off.astype(int), 0]))
        for start, stop in zip(edges[::2], edges[1::2]):
            ax.axvspan(t[start], t[min(stop, len(t) - 1)], color='tab:red', alpha=0.12, lw=0,
                       label='disconnected span' if start == edges[0] else None)


def time_series(series: Sequence[tuple[str, np.ndarray, np.ndarray]], ylabel: str, title: str,
                path: Path, events: Sequence[Event] = ()) -> Path:
    """One line per (label, t, y)."""
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for label, t, y in series:
        ax.plot(t, y, label=label, lw=1.6)
    finish(ax, 'time t (s)', ylabel, title, events)
    return save(fig, path)


def fiedler_series(series: Sequence[tuple[str, np.ndarray, np.ndarray]], title: str, path: Path,
                   events: Sequence[Event] = ()) -> Path:
    """lambda2 over time on the Fiedler axis; one run's disconnected spans shaded."""
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for label, t, y in series:
        ax.plot(t, y, label=label if len(series) > 1 else None, lw=1.6)
    fiedler_axis(ax, *(series[0][1:] if len(series) == 1 else (None, None)))
    finish(ax, 'time t (s)', FIEDLER_LABEL, title, events)
    return save(fig, path)


def channel(t: np.ndarray, metrics: np.ndarray, title: str, path: Path, events: Sequence[Event] = ()) -> Path:
    """A run under a channel: lambda2 of the disc, usable and heard graphs above, the share of neighbour
    states heard below (metrics rows with hearing.LINK_COLUMNS after METRICS_COLUMNS)."""
    fig, (top, low) = plt.subplots(2, 1, figsize=(6.4, 5.6), sharex=True, height_ratios=(2, 1))
    for col, name in ((3, 'disc graph'), (9, 'usable graph (delivery ≥ 0.5)'), (11, 'heard graph (last 1 s)')):
        top.plot(t, metrics[:, col], lw=1.4, label=name)
    fiedler_axis(top)
    finish(top, '', FIEDLER_LABEL, title, events)
    low.plot(t, 100 * metrics[:, 13], lw=1.2, color='tab:grey')
    finish(low, 'time t (s)', 'states heard (%)', '')
    return save(fig, path)


def flight(t: np.ndarray, metrics: np.ndarray, separation: float, title: str, path: Path,
           events: Sequence[Event] = ()) -> Path:
    """A multirotor's run: coverage, the formation's mean propulsion power against hover, and the least distance
    between two MAPs against the separation they must keep, on one time axis (records.VEHICLE_COLUMNS)."""
    from world_sim.core.vehicle import HOVER
    fig, (cov, power, apart) = plt.subplots(3, 1, figsize=(6.4, 7.2), sharex=True)
    cov.plot(t, 100 * metrics[:, 2], lw=1.4, color='tab:blue')
    cov.set_ylim(0, 100)
    finish(cov, '', 'coverage R_c (%)', title, events)
    power.plot(t, records.vehicle_column(metrics, 'power'), lw=1.4, color='tab:red', label='mean per MAP')
    power.axhline(HOVER, color='grey', ls='--', lw=1, label=f'hover ({HOVER:.1f} W)')
    finish(power, '', 'propulsion power (W)', '')
    apart.plot(t, records.vehicle_column(metrics, 'min_distance'), lw=1.2, color='tab:green', label='least distance')
    apart.axhline(separation, color='tab:red', ls='--', lw=1, label=f'separation ({separation:g} m)')
    apart.set_ylim(bottom=0)
    finish(apart, 'time t (s)', 'least distance\nbetween two MAPs (m)', '')
    return save(fig, path)


def command_difference(t: np.ndarray, du: np.ndarray, tolerance: float, title: str, path: Path) -> Path:
    """|Δu| of a replay against the recording over time, on a log axis where 1e-12 and 1 both read."""
    fig, ax, floor = *plt.subplots(figsize=(6.4, 3.6)), tolerance / 100 if tolerance > 0 else 1e-15
    ax.semilogy(t, np.maximum(du, floor), lw=1.2, label='|Δu|, replayed - recorded')
    ax.axhline(max(tolerance, floor), color='grey', ls='--', lw=1, label=f'tolerance {tolerance:g}')
    ax.set_ylim(floor / 10, 10 * max(float(np.max(du, initial=0.0)), 10 * max(tolerance, floor)))  # never one value
    finish(ax, 'time t (s)', '|Δu| (m/s², log)', title)
    return save(fig, path)


def mode_counts(t: np.ndarray, counts: np.ndarray, title: str, path: Path) -> Path:
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for m in range(3):
        ax.plot(t, counts[:, m], color=MODE_COLOURS[m], label=MODE_NAMES[m], lw=1.6)
    finish(ax, 'time t (s)', 'MAPs in mode', title)
    return save(fig, path)


def links_within(q: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
    """The links within r, each once, as one polyline (x, y; NaN between links): 5000 MAPs packed took 40 s a path a link."""
    pairs = neighbour_pairs(np.reshape(q, (-1, 2)), r)
    pairs = pairs[pairs[:, 0] < pairs[:, 1]]  # each link once
    line = np.stack([q[pairs[:, 0]], q[pairs[:, 1]], np.full((len(pairs), 2), np.nan)], axis=1)
    return line[:, :, 0].ravel(), line[:, :, 1].ravel()


def legend_handles(r: float, lost: bool = False, tracks: bool = False) -> list[plt.Line2D]:
    """The formation's legend in reading order, with every mode whether or not a picture shows it."""
    handles = [plt.Line2D([], [], ls='', marker='o', ms=3, color='0.75', label='MSD')]
    handles += [plt.Line2D([], [], ls='', marker='o', ms=5, color=c, label=n) for c, n in zip(MODE_COLOURS, MODE_NAMES)]
    handles += [plt.Line2D([], [], ls='', marker='x', ms=7, color='k', label='cluster centroid'),
                plt.Line2D([], [], color='0.35', lw=0.8, label=f'link (within r = {r:g} m)')]
    if lost:
        handles.append(plt.Line2D([], [], ls='', marker='X', ms=6, color='tab:red', label='MAP lost'))
    if tracks:
        handles.append(plt.Line2D([], [], color='tab:purple', lw=1.0, label='cluster track'))
    return handles


def formation(ax: plt.Axes, users_xy: np.ndarray, users_cluster: np.ndarray, centroids: np.ndarray,
              q: np.ndarray, mode: np.ndarray, r: float, title: str) -> None:
    """MSDs (grey, by cluster), MAPs coloured by mode, MAP-MAP links within r, cluster centroids."""
    ax.scatter(users_xy[:, 0], users_xy[:, 1], s=2, c='0.75', zorder=1, label='MSD')
    if len(q):
        ax.plot(*links_within(q[:, :2], r), color='0.35', lw=0.5, zorder=2)
    for m in range(3):
        sel = mode == m
        if np.any(sel):
            ax.scatter(q[sel, 0], q[sel, 1], s=14, c=MODE_COLOURS[m], zorder=3, label=MODE_NAMES[m])
    ax.scatter(centroids[:, 0], centroids[:, 1], marker='x', s=50, c='k', zorder=4, label='cluster centroid')
    ax.set_aspect('equal')
    ax.set_xlabel('x (m)')
    ax.set_ylabel('y (m)')
    ax.set_title(title, fontsize=9)


def lost_at(traj: dict[str, np.ndarray], t: float) -> np.ndarray:
    """Where each MAP that flew before t and no longer does at t was last, (n, 2)."""
    before, now = traj['t'] < t, traj['t'] == t
    gone = np.setdiff1d(np.unique(traj['id'][before]), traj['id'][now])
    if not len(gone):
        return np.zeros((0, 2))
    rows = np.flatnonzero(before & np.isin(traj['id'], gone))
    last = {int(traj['id'][i]): i for i in rows}  # rows run in time order: the last one stays
    return np.array([[traj['x'][i], traj['y'][i]] for i in last.values()])


def formation_snapshots(traj: dict[str, np.ndarray], users_xy: np.ndarray, users_cluster: np.ndarray,
                        centroids: np.ndarray, r: float, times: Sequence[float], title: str, path: Path,
                        users_at: UsersAt | None = None) -> Path:
    """Formation at several times, side by side, sharing one legend; users_at gives the MSDs at a time
    when they move (their centroids are then those of each cluster at that time)."""
    all_t = np.unique(traj['t'])
    shown = [all_t[np.argmin(np.abs(all_t - want))] for want in times]
    panels = {t: (users_xy, users_cluster, centroids) for t in shown}
    if users_at is not None:
        for t in shown:
            xy, cl = users_at(float(t))
            panels[t] = (xy, cl, np.array(list(label_centroids(xy, cl).values())).reshape(-1, 2))
    # One frame for every panel, fitted to what they show, so the panels fill the figure.
    pts = np.vstack([*(v[0] for v in panels.values()), np.column_stack([traj['x'][np.isin(traj['t'], shown)],
                                                traj['y'][np.isin(traj['t'], shown)]])])
    lo, hi = pts.min(axis=0) - 10.0, pts.max(axis=0) + 10.0
    width = 3.6 * (hi[0] - lo[0]) / max(hi[1] - lo[1], 1e-9)
    fig, axes = plt.subplots(1, len(times), figsize=(min(max(width, 2.4), 5.0) * len(times) + 0.6, 4.6),
                             squeeze=False)
    any_lost = False
    for ax, t in zip(axes[0], shown):
        sel = traj['t'] == t
        q = np.column_stack([traj['x'][sel], traj['y'][sel]])
        formation(ax, *panels[t], q, traj['mode'][sel].astype(int), r, f't = {t:.1f} s')
        gone = lost_at(traj, t)
        if len(gone):
            any_lost = True
            ax.scatter(gone[:, 0], gone[:, 1], marker='X', s=30, c='tab:red', zorder=5)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
    handles = legend_handles(r, lost=any_lost)
    fig.legend(handles=handles, loc='lower center', ncol=len(handles), fontsize=8, frameon=False)
    fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.08, 1, 0.96))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def formation_animation(traj: dict[str, np.ndarray], users_xy: np.ndarray, users_cluster: np.ndarray, r: float,
                        title: str, path: Path, users_at: UsersAt | None = None, every: float = 1.0,
                        fps: int = 5, metrics: np.ndarray | None = None) -> Path:
    """The formation as an animated GIF, one frame per `every` s of simulated time: MSDs, MAPs by mode,
    links within r, cluster centroids and the tracks of moving clusters so far, MAPs lost marked where they
    were last, and (given the run's metrics rows) R_c and λ2 of the frame's step. A picture to watch where
    snapshots leave gaps; kept small (about 1 MB for 90 s)."""
    all_t = np.unique(traj['t'])
    shown = sorted({all_t[np.argmin(np.abs(all_t - want))] for want in np.arange(0.0, all_t[-1] + 1e-9, every)}
                   | {all_t[-1]})
    users = {t: (users_xy, users_cluster) if users_at is None else users_at(float(t)) for t in shown}
    movie = FormationMovie(traj, shown, users, r, title, metrics)
    return movie.write(path, fps)


class FormationMovie:
    """The artists of formation.gif over axes drawn once; each frame redraws only what moves (blitting).

    Every frame takes the first frame's palette, which the legend fills with every colour drawn: a colour
    never shifts between frames, and Pillow quantizes once."""

    def __init__(self, traj: dict[str, np.ndarray], shown: list[float],
                 users: dict[float, tuple[np.ndarray, np.ndarray]], r: float, title: str,
                 metrics: np.ndarray | None) -> None:
        self.traj, self.shown, self.users, self.r, self.title, self.metrics = traj, shown, users, r, title, metrics
        self.centroids = [label_centroids(*users[t]) for t in shown]
        self.rows = [np.flatnonzero(traj['t'] == t) for t in shown]
        pts = np.vstack([*(u[0] for u in users.values()),
                         np.column_stack([traj['x'], traj['y']])[np.concatenate(self.rows)]])
        lo, hi = pts.min(axis=0) - 15.0, pts.max(axis=0) + 15.0
        # The figure is cut to the axes' own shape (equal scales, within 1:2 and 7:5), so no band is left empty
        # around them; 480 px wide at 96 dpi, where the text reads.
        span = hi - lo
        aspect = float(np.clip(span[1] / max(span[0], 1e-9), 0.5, 1.4))
        grow = np.maximum(np.array([span[1] / aspect, span[0] * aspect]) - span, 0.0)
        lo, hi = lo - grow / 2, hi + grow / 2
        width, left, right, top, bottom = 5.0, 0.7, 0.15, 0.5, 0.95  # inches: labels above, ticks and legend below
        height = (width - left - right) * aspect + top + bottom
        self.fig, ax = plt.subplots(figsize=(width, height))
        ax.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]), xlabel='x (m)', ylabel='y (m)')
        ax.set_aspect('equal')
        self.msd = ax.scatter(*users[shown[0]][0].T, s=2, c='0.75', zorder=1)
        self.links = ax.plot([], [], color='0.35', lw=0.5, zorder=2)[0]
        self.tracks = {k: ax.plot([], [], color='tab:purple', lw=1.0, zorder=2)[0] for c in self.centroids for k in c}
        self.maps = [ax.scatter([], [], s=14, c=colour, zorder=3) for colour in MODE_COLOURS]
        self.marks = ax.scatter([], [], marker='x', s=50, c='k', zorder=4)
        self.lost = ax.scatter([], [], marker='X', s=40, c='tab:red', zorder=5)
        self.heading = ax.set_title('', fontsize=9)
        self.last_seen: dict[int, np.ndarray] = {}
        self.fig.legend(handles=legend_handles(r, lost=True, tracks=True), loc='lower center', ncol=3, fontsize=7,
                        frameon=False, borderaxespad=0.2, handletextpad=0.3, columnspacing=1.0)
        self.fig.subplots_adjust(left=left / width, right=1.0 - right / width, bottom=bottom / height,
                                 top=1.0 - top / height)
        self.fig.set_dpi(96)

    def readout(self, t: float) -> str:
        if self.metrics is None or not len(self.metrics):
            return ''
        row = self.metrics[np.argmin(np.abs(self.metrics[:, 1] - t))]
        return f'   R_c = {100 * row[2]:.1f} %   λ2 = {row[3]:.4f}{" (split)" if row[3] <= 0 else ""}'

    def draw(self, n: int) -> None:
        traj, t, sel = self.traj, self.shown[n], self.rows[n]
        q = np.column_stack([traj['x'][sel], traj['y'][sel]])
        ids, mode = traj['id'][sel].astype(int).tolist(), traj['mode'][sel].astype(int)
        self.msd.set_offsets(self.users[t][0])
        self.links.set_data(*links_within(q, self.r))
        for m, artist in enumerate(self.maps):
            artist.set_offsets(q[mode == m] if np.any(mode == m) else np.zeros((0, 2)))
        self.marks.set_offsets(np.array(list(self.centroids[n].values())).reshape(-1, 2))
        for k, line in self.tracks.items():
            path_k = np.array([c[k] for c in self.centroids[:n + 1] if k in c]).reshape(-1, 2)
            moved = len(path_k) > 1 and np.ptp(path_k, axis=0).max() > 1.0
            line.set_data(*(path_k.T if moved else ([], [])))
        here = set(ids)
        self.lost.set_offsets(np.array([q_i for i, q_i in self.last_seen.items() if i not in here]).reshape(-1, 2))
        self.last_seen.update(zip(ids, q))
        self.heading.set_text(f'{self.title}\nt = {t:.0f} s{self.readout(t)}')

    def write(self, path: Path, fps: int) -> Path:
        from PIL import Image
        moving = [self.msd, self.links, *self.tracks.values(), *self.maps, self.marks, self.lost, self.heading]
        for artist in moving:
            artist.set_animated(True)
        canvas = self.fig.canvas
        canvas.draw()
        background = canvas.copy_from_bbox(self.fig.bbox)
        images: list[Image.Image] = []
        palette = None
        for n in range(len(self.shown)):
            self.draw(n)
            canvas.restore_region(background)
            for artist in moving:
                self.fig.draw_artist(artist)
            frame = Image.fromarray(np.asarray(canvas.buffer_rgba())[..., :3].copy())
            palette = palette or frame.quantize(colors=255, dither=Image.Dither.NONE)  # the first frame's colours
            images.append(frame.quantize(palette=palette, dither=Image.Dither.NONE))  # each mapped the same way
        images[0].save(path, save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0)
        plt.close(self.fig)
        return path


def run_figures(metrics: np.ndarray, traj: dict[str, np.ndarray], users_xy: np.ndarray | None,
                users_cluster: np.ndarray | None, centroids: np.ndarray | None, r: float, label: str,
                folder: Path, events: Sequence[Event] = (), users_at: UsersAt | None = None,
                radio: str | None = None, separation: float | None = None) -> list[Path]:
    """The figures of one run: coverage, Fiedler value, mode counts, formation snapshots and animation.

    metrics rows follow the METRICS_COLUMNS order; without MSDs the formation pictures are left out; radio: the
    channel between MAPs in words, for links.png's title; separation: a multirotor's (flight.png). The
    animation, the costliest, is drawn by a forked child meanwhile (on a machine of one core, here after).
    """
    animated = users_xy is not None and users_cluster is not None and centroids is not None and len(traj['t'])
    gif = folder / 'formation.gif'
    child = Meanwhile(lambda: formation_animation(traj, users_xy, users_cluster, r, label, gif, users_at,
                                                  metrics=metrics)) if animated else None
    try:
        t = metrics[:, 1]
        out = [
            time_series([(label, t, 100 * metrics[:, 2])], 'coverage ratio R_c (%)', f'Coverage, {label}',
                        folder / 'coverage.png', events),
            fiedler_series([(label, t, metrics[:, 3])], f'Connectivity, {label}', folder / 'fiedler.png', events),
            mode_counts(t, metrics[:, 6:9], f'Modes, {label}', folder / 'modes.png'),
        ]
        if records.has_links(metrics):  # under a channel: the graphs of what the MAPs could and did hear (hearing.py)
            out.append(channel(t, metrics, f'Radio between MAPs, {label}' + (f'\n{radio}' if radio else ''),
                               folder / 'links.png', events))
        if separation is not None and records.vehicle_column(metrics, 'power') is not None:
            out.append(flight(t, metrics, separation, f'Flight, {label}', folder / 'flight.png', events))
        if child is not None:
            end = float(traj['t'].max())
            times = sorted({0.0, round(end / 4, 1), round(end / 2, 1), end})
            out.append(formation_snapshots(traj, users_xy, users_cluster, centroids, r, times,
                                           f'Formation, {label}', folder / 'formation.png', users_at))
            child.wait(f'drawing {gif}')
            out.append(gif)
        return out
    finally:
        if child is not None:
            child.stop()


class Meanwhile:
    """A drawing done by a forked child while this process goes on: two cores draw two pictures at once.

    The child shares what this process holds at the fork (no pickling) and leaves by os._exit, as
    multiprocessing's children do, so it tears nothing of ours down. Ctrl-C is this process's to act on."""

    def __init__(self, draw: Callable[[], object]) -> None:
        import multiprocessing
        self.child = None
        if (os.cpu_count() or 1) < 2 or 'jax' in sys.modules:  # JAX's threads (airframe x500) are not forked
            draw()
            return
        self.child = multiprocessing.get_context('fork').Process(target=_quietly, args=(draw,), daemon=True)
        self.child.start()

    def wait(self, what: str) -> None:
        if self.child is None:
            return
        self.child.join()
        if self.child.exitcode != 0:
            raise RuntimeError(f'{what} failed (exit {self.child.exitcode}; its error is above)')

    def stop(self) -> None:
        if self.child is not None and self.child.exitcode is None:
            self.child.terminate()
            self.child.join()


def _quietly(draw: Callable[[], object]) -> None:
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent stops it on Ctrl-C; no traceback of its own
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    draw()
