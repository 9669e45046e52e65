"""`uav-flock trace`: a run flown again, saying what split the network and why a MAP moved.

A study row, or a run's metrics.csv, says that a run split; the trace says where and who. It flies the run again as
the study or `sim` flew it (the same steps, to the bit) and prints, from --from to --to: each change of the pieces
the MAP graph within r falls into, with the MAPs each smaller piece holds and the links whose breaking made the
split; and, every --every seconds, for each MAP asked about, its role, where its plan aims it, its nominal (eq. 9 as
the vehicle flies it), the command the safety filter or the rules made of it, what the filter did, and the links it
was asked to keep.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Iterable, NamedTuple, Optional, TextIO

import numpy as np
from uav_agent.core.safety import AWAY, HELD, RELAXED, RELEASED
from uav_agent.core.state import ALONE, M1, SHARED, Memory
from world_sim.core.physics import component_labels

if TYPE_CHECKING:
    from .batch import BatchSimulator, Decided
    from .study.spec import Run

CUT_OFF_SHOWN = 12  # MAPs named per piece cut off; the rest counted
BROKEN_SHOWN = 6    # links named per split
# What the filter (and its liveness, agent.after_filter) did to a command, by flag bit (Command.msg's filter).
FILTER_SAID = ((HELD, 'held back by a link'), (RELAXED, 'a link gave way'), (AWAY, 'away from its goal'),
               (RELEASED, 'released from its links'))


@dataclass(frozen=True)
class Window:
    """What to trace: the MAPs to follow, from t0 to t1 (s), a line each `every` s."""

    maps: tuple[int, ...] = ()
    t0: float = 0.0
    t1: float = float('inf')
    every: float = 1.0


def pick(runs: Iterable[Run], which: str, variant: Optional[str]) -> Run:
    """The run `which` names: its key, or LAYOUT/SEED/KIND (a kind as the study names it, drift:2); with several
    variants, --variant says which. ValueError, one line, when it names none or several."""
    runs = list(runs)
    variants = sorted({r.variant for r in runs})
    if variant is not None and variant not in variants:
        raise ValueError(f'no variant {variant!r} in the spec (it has {", ".join(variants)})')
    found = [r for r in runs if r.key == which]
    if not found:
        parts = which.split('/')
        if len(parts) != 3 or not parts[0].isdigit() or not parts[1].isdigit():
            raise ValueError(f'{which!r} is neither a run key of the spec nor LAYOUT/SEED/KIND (say 3/0/drift:2)')
        layout, seed, kind = int(parts[0]), int(parts[1]), parts[2]
        found = [r for r in runs if (r.layout, r.seed, r.kind) == (layout, seed, kind)]
        if not found:
            kinds = sorted({r.kind for r in runs})
            raise ValueError(f'no run {which} in the spec (layouts 0-{max(r.layout for r in runs)}, seeds '
                             f'{", ".join(map(str, sorted({r.seed for r in runs})))}, kinds {", ".join(kinds)})')
    if variant is not None:
        found = [r for r in found if r.variant == variant]
    if len({r.variant for r in found}) > 1:
        raise ValueError(f'{which} is flown by {len(found)} variants: say which with --variant '
                         f'({", ".join(r.variant for r in found)})')
    return found[0]


def role(mem: Memory) -> str:
    """A MAP's role as the trace writes it: S3 a server of cluster 3, R(1, 4) a relay of edge (1, 4); then how far
    it is with it under the demand allocation: on its first flight, settled, or in transit to a new role."""
    name = f'R{tuple(mem.bridge)}' if mem.mode == M1 and mem.bridge is not None else f'S{mem.goal}'
    own = mem.own
    if not hasattr(own, 'settled'):
        return name
    return f'{name} ' + ('in transit' if own.transit else 'settled' if own.settled else 'first flight')


def _who(decided: Decided, link: int) -> str:
    """The MAP a link's neighbour state came from: the live MAP at that very place (a state of this step), else
    '?' (a state heard late, under a lossy radio, is where its sender was)."""
    at = np.flatnonzero(np.all(decided.sensed.q == decided.nbr_q[link], axis=1))
    return str(int(decided.sensed.ids[at[0]])) if len(at) else '?'


def _vec(a: np.ndarray) -> str:
    return f'{float(np.hypot(a[0], a[1])):.1f} m/s² ({a[0]:+.1f}, {a[1]:+.1f})'


def map_line(sim: BatchSimulator, i: int, t: float) -> str:
    """One MAP at one step: role, speed, aim, nominal, command, what the filter did, the links it keeps."""
    d = sim.decided
    rows = np.flatnonzero(d.sensed.ids == i)
    if not len(rows):
        return f't={t:7.1f}  MAP {i}: lost'
    n = int(rows[0])
    q, p, ref = d.sensed.q[n], d.sensed.p[n], d.refs[n]
    aim = (ref.q1 + ref.q2) / 2 if ref.mode == M1 else ref.target  # a relay aims at its slot on the edge
    said = [text for bit, text in FILTER_SAID if int(d.control.flags[n]) & bit]
    links = np.flatnonzero((d.owner == n) & (d.needed != 0))
    keeps = [f'{_who(d, j)} {"alone" if d.needed[j] == ALONE else "shared" if d.needed[j] == SHARED else ""} '
            f'{float(np.hypot(*(d.nbr_q[j, :2] - q[:2]))):.1f} m' for j in links]
    nominal, command = d.control.nominal[n], d.control.u[n]
    changed = 'the same' if np.allclose(nominal, command, atol=1e-9) else _vec(command)
    return (f't={t:7.1f}  MAP {i} {role(sim.memory[i])}, {float(np.hypot(p[0], p[1])):.1f} m/s, '
            f'{float(np.hypot(*(aim[:2] - q[:2]))):.1f} m from its aim; nominal {_vec(nominal)}, command {changed}'
            + (f'; {", ".join(said)}' if said else '') + (f'; keeps {", ".join(keeps)}' if keeps else ''))


def _described(sim: BatchSimulator, ids: np.ndarray, rows: np.ndarray, p: np.ndarray) -> str:
    named = ', '.join(f'{int(ids[j])} {role(sim.memory[int(ids[j])])} {float(np.hypot(p[j, 0], p[j, 1])):.1f} m/s'
                      for j in rows[:CUT_OFF_SHOWN])
    return named + (f' and {len(rows) - CUT_OFF_SHOWN} more' if len(rows) > CUT_OFF_SHOWN else '')


class Outage(NamedTuple):
    """A time the MAP graph within r was in more than one piece, from its first split to one network again (s), and
    what began it (began)."""

    start: float
    end: float
    began: str


class Traced(NamedTuple):
    """What a trace saw in its window: how often the network split, and each time it was apart."""

    splits: int
    outages: list[Outage]

    @property
    def apart(self) -> float:
        """Seconds the network was in more than one piece within the window."""
        return sum(o.end - o.start for o in self.outages)


ALREADY = 'in pieces when the window opened'


def began(needs: bool, ends: Iterable[str]) -> str:
    """What began an outage, from the links whose breaking split one network: a link the network needs (the filter's)
    that gave way; else a link to a MAP in transit to a new role, or on its first flight, or between settled MAPs
    (role's words, the most mobile first)."""
    if needs:
        return 'a link the network needs gave way'
    said = ' '.join(ends)
    for words, what in (('in transit', 'a MAP in transit'), ('first flight', 'a MAP on its first flight'),
                        ('settled', 'settled MAPs')):
        if words in said:
            return f'a link kept by neither end, of {what}'
    return 'a link kept by neither end'


class Pieces:
    """The MAP graph within r, step by step: what changed since the step before, and what began the last split of
    one network (began)."""

    def __init__(self) -> None:
        self.count: Optional[int] = None
        self.links: set[tuple[int, int]] = set()
        self.needed: set[tuple[int, int]] = set()
        self.began = ''

    def changed(self, sim: BatchSimulator, t: float, report: bool) -> list[str]:
        d = sim.decided
        s = d.sensed
        ids, truth = s.ids, s.truth if s.truth is not None else s.q
        label = component_labels(s.pairs, len(ids))
        count = int(label.max()) + 1 if len(ids) else 0
        links = {(int(ids[a]), int(ids[b])) for a, b in s.pairs if a < b}
        lines: list[str] = []
        if report and self.count is not None and count != self.count:
            sizes = np.bincount(label)
            lines.append(f't={t:7.1f}  pieces {self.count} -> {count}: '
                         f'{", ".join(map(str, sorted(sizes.tolist(), reverse=True)))} MAPs')
            big = int(sizes.argmax())
            for c in range(count):
                if c != big:
                    lines.append(f'           cut off: {_described(sim, ids, np.flatnonzero(label == c), s.p)}')
            if count > self.count:
                where = dict(zip(ids.tolist(), label.tolist()))
                broke = sorted((a, b) for a, b in self.links - links
                               if a in where and b in where and where[a] != where[b])
                at = {int(i): n for n, i in enumerate(ids)}
                for a, b in broke[:BROKEN_SHOWN]:
                    length = float(np.linalg.norm(truth[at[a], :2] - truth[at[b], :2]))
                    needs = (a, b) in self.needed or (b, a) in self.needed
                    asked = 'a link the network needs' if needs else 'kept by neither end'
                    lines.append(f'           broke: {a} {role(sim.memory[a])} - {b} {role(sim.memory[b])}, '
                                 f'{length:.1f} m; the step before, {asked}')
                self.began = began(any((a, b) in self.needed or (b, a) in self.needed for a, b in broke),
                                   (role(sim.memory[i]) for link in broke for i in link))
        self.count, self.links = count, links
        if report:  # for the next step's broken links; not looked up outside the window, where nothing is said
            owners = s.ids[d.owner]
            self.needed = {(int(owners[j]), int(w)) for j in np.flatnonzero(d.needed != 0)
                           if (w := _who(d, int(j))) != '?'}
        return lines


def trace(steps: Iterable[BatchSimulator], window: Window, out: TextIO) -> Traced:
    """Follow a run's steps (engine.flight(..., watch=True), or BatchSimulator(s, watch=True).flight()) and write
    what the window asks for; the splits seen in it, and each time the network was apart within it."""
    pieces, splits, every = Pieces(), 0, None
    outages: list[Outage] = []
    apart: Optional[tuple[float, str]] = None  # an outage open since, begun by
    t = window.t0
    for sim in steps:
        d = sim.decided
        t = d.sensed.k * sim.scenario.dt
        inside = window.t0 <= t + 1e-9 <= window.t1 + 2e-9
        before = pieces.count
        lines = pieces.changed(sim, t, inside or window.t0 - sim.scenario.dt <= t + 1e-9 < window.t0)
        for line in (lines if inside else ()):
            print(line, file=out)
        splits += int(inside and before is not None and pieces.count > before)
        if inside and apart is None and (pieces.count or 0) > 1:
            apart = (t, pieces.began if before == 1 else ALREADY)
        elif inside and apart is not None and pieces.count == 1:
            outages.append(Outage(apart[0], t, apart[1]))
            apart = None
        if inside and window.maps and (every is None or t >= every - 1e-9):
            for i in window.maps:
                print(map_line(sim, i, t), file=out)
            every = t + window.every
        out.flush()  # each step as it is flown: a reader that leaves (`| head`) is seen at once, never at exit
        if t > window.t1:
            break
    if apart is not None:
        outages.append(Outage(apart[0], min(t, window.t1), apart[1]))
    return Traced(splits, outages)


def summary(traced: Traced, window: Window) -> list[str]:
    """The trace's last lines: how often the network split in the window, how long it was apart, and each outage
    with what began it."""
    splits, outages = traced
    head = f'trace: {splits} split{"s" if splits != 1 else ""} from {window.t0:g} s to {window.t1:g} s'
    if not outages:
        return [head + '; one network throughout' if splits == 0 else head]
    total, span = traced.apart, window.t1 - window.t0
    share = f' ({100.0 * total / span:.1f} %)' if span > 0 else ''
    lines = [f'{head}; apart {total:.1f} s of the {span:g} s{share}, in {len(outages)} outage'
             f'{"s" if len(outages) != 1 else ""}:']
    return lines + [f'  {o.start:6.1f}-{o.end:.1f} s ({o.end - o.start:.1f} s), begun by {o.began}' for o in outages]


class Census(NamedTuple):
    """What kept a study's networks apart after first convergence: per (what began an outage, whether the run had
    not yet formed then), the seconds apart and the outages; and the seconds after first convergence in all (the
    time the `connected` column is a share of), over the runs that converged."""

    apart: dict[tuple[str, bool], tuple[float, int]]
    window: float
    runs: int


def census(runs: Iterable[tuple[float, float, Optional[float], Traced]]) -> Census:
    """The census of runs, each (its first convergence, its end, when it formed or None, its outages traced from its
    first convergence on). An outage counts as before `formed` (the study's column: covered, connected and every MAP
    slower than 3 m/s) when it began before the formation first came to rest: MAPs still on their way to it."""
    apart: dict[tuple[str, bool], tuple[float, int]] = {}
    window, count = 0.0, 0
    for converged, end, formed, traced in runs:
        window += end - converged
        count += 1
        for o in traced.outages:
            key = (o.began, formed is None or o.start < formed)
            s, n = apart.get(key, (0.0, 0))
            apart[key] = (s + o.end - o.start, n + 1)
    return Census(apart, window, count)


def census_lines(c: Census) -> list[str]:
    """The census as a table: each kind of outage's seconds, its share of all the time after first convergence, and
    how many, before and after the formations formed; then the whole."""
    total = sum(s for s, _ in c.apart.values())
    share = (lambda s: f'{100.0 * s / c.window:5.2f} %') if c.window > 0 else (lambda s: '    - ')
    runs = f'{c.runs} run{"s" if c.runs != 1 else ""}'
    lines = [f'outages after first convergence, {runs}, {c.window:.1f} s after it in all; '
             f'apart {total:.1f} s ({share(total).strip()}):',
             f'  {"begun by":<62} {"formed":<7} {"s":>7} {"of the time":>11} {"outages":>8}']
    for (what, early), (s, n) in sorted(c.apart.items(), key=lambda kv: -kv[1][0]):
        lines.append(f'  {what:<62} {"not yet" if early else "after":<7} {s:7.1f} {share(s):>11} {n:8d}')
    if not c.apart:
        lines.append('  none: one network from each first convergence to its end')
    return lines
