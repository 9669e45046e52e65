"""Which MAP keys each role owns: pieces of [0, 1), carried from one survey to the next.

A MAP's role is the role whose piece holds its key (clusters.key_of). Laid out afresh at every survey, the
shares would sit end to end, and one cluster growing, merging or leaving would shift every boundary after
it: most MAPs would change role at once and cross the field. Carried instead, a role that shrinks gives up
only the keys it no longer needs, a role that grows takes only what it lacks, and every other MAP keeps
its role (docs/dynamics.md, "Keys carried across surveys").

Every MAP carries the layout itself, from the surveys it has heard; MAPs that heard the same surveys hold
the same layout, with no message exchanged.
"""
from __future__ import annotations

from typing import Iterable, Sequence, Union

RoleId = Union[int, tuple[int, int]]  # a cluster's id, or an MST edge (a, b): what stays the same across surveys
Piece = tuple[float, float, RoleId]   # keys [lo, hi) belong to the role
SLIVER = 0.002  # a piece thinner than this is a fragment (a sixth of the key spacing of 80 MAPs); it joins a neighbour
_EPS = 1e-12
_FREE = None  # a piece given up and not yet taken


def fresh(shares: Iterable[tuple[RoleId, float, float]]) -> tuple[Piece, ...]:
    """The first layout: one piece [start, end) per role, end to end, empty roles left out."""
    return tuple((lo, hi, role) for role, lo, hi in shares if hi > lo)


def totals(pieces: Iterable[Piece]) -> dict[RoleId, float]:
    """How much of [0, 1) each role holds."""
    held: dict[RoleId, float] = {}
    for lo, hi, role in pieces:
        held[role] = held.get(role, 0.0) + hi - lo
    return held


def carry(old: Sequence[Piece], shares: dict[RoleId, float]) -> tuple[Piece, ...]:
    """The layout after a survey: old, with each role's holding brought to its new share (shares, in role
    order, summing to 1), moving as few keys as it can.

    1. Neighbours trade at their common boundary: a growing role takes from a shrinking one it touches,
       so a share that moves a little moves the boundary a little, as end to end.
    2. A role still holding too much gives up its smallest pieces whole, then the high end of its largest.
    3. A role still short takes a free piece next to one of its own, else the largest free piece.
    4. Free keys left by rounding, and fragments thinner than SLIVER, join the piece before them.
    """
    if not old:
        return fresh(end_to_end(shares))
    held = totals(old)
    spare = {role: held[role] - shares.get(role, 0.0) for role in held}
    need = {role: share - held.get(role, 0.0) for role, share in shares.items()}
    pieces = _traded([list(p) for p in old], spare, need)
    pieces = _given_up(pieces, spare)
    pieces = _taken(pieces, need)
    return _tidied(pieces)


def _traded(pieces: list[list], spare: dict[RoleId, float], need: dict[RoleId, float]) -> list[list]:
    """Step 1 of carry: neighbours trade at their common boundary (spare and need are updated)."""
    for a, b in zip(pieces, pieces[1:]):
        if spare.get(a[2], 0.0) > _EPS and need.get(b[2], 0.0) > _EPS:
            t = min(spare[a[2]], need[b[2]], a[1] - a[0])
            a[1] -= t
            b[0] -= t
            spare[a[2]] -= t
            need[b[2]] -= t
        elif need.get(a[2], 0.0) > _EPS and spare.get(b[2], 0.0) > _EPS:
            t = min(need[a[2]], spare[b[2]], b[1] - b[0])
            a[1] += t
            b[0] += t
            need[a[2]] -= t
            spare[b[2]] -= t
    return [p for p in pieces if p[1] - p[0] > _EPS]


def _given_up(pieces: list[list], spare: dict[RoleId, float]) -> list[list]:
    """Step 2 of carry: a role still holding too much frees its smallest pieces, then its largest's high end."""
    for role, extra in spare.items():
        mine = sorted((p for p in pieces if p[2] == role), key=lambda p: (p[1] - p[0], p[0]))
        for p in mine[:-1]:
            if extra > _EPS and p[1] - p[0] <= extra + _EPS:
                extra -= p[1] - p[0]
                p[2] = _FREE
        if extra > _EPS and mine:
            largest = mine[-1]
            cut = min(extra, largest[1] - largest[0])
            pieces.append([largest[1] - cut, largest[1], _FREE])
            largest[1] -= cut
        pieces = _merged([p for p in pieces if p[1] - p[0] > _EPS])
    return pieces


def _taken(pieces: list[list], need: dict[RoleId, float]) -> list[list]:
    """Step 3 of carry: a role still short takes a free piece next to one of its own, else the largest free one."""
    for role, short in need.items():
        while short > _EPS:
            free = [i for i, p in enumerate(pieces) if p[2] is _FREE]
            if not free:
                break
            after = [i for i in free if i > 0 and pieces[i - 1][2] == role]
            before = [i for i in free if i + 1 < len(pieces) and pieces[i + 1][2] == role]
            i = (after + before)[0] if after or before else max(free, key=lambda j: (pieces[j][1] - pieces[j][0], -j))
            lo, hi, _ = pieces[i]
            t = min(short, hi - lo)
            if i in after or i not in before:  # grow from the role's piece below it (or from the low end)
                parts = [[lo, lo + t, role], [lo + t, hi, _FREE]]
            else:
                parts = [[lo, hi - t, _FREE], [hi - t, hi, role]]
            pieces[i:i + 1] = [p for p in parts if p[1] - p[0] > _EPS]
            pieces = _merged(pieces)
            short -= t
    return pieces


def _tidied(pieces: list[list]) -> tuple[Piece, ...]:
    """Step 4 of carry: free keys left by rounding, and slivers, join the piece before them."""
    largest: dict[RoleId, float] = {}
    for lo, hi, role in pieces:
        largest[role] = max(largest.get(role, 0.0), hi - lo)
    out: list[list] = []
    for p in pieces:
        fragment = p[2] is _FREE or (p[1] - p[0] < SLIVER and p[1] - p[0] < largest[p[2]])
        if fragment and out:
            out[-1][1] = p[1]
        else:
            out.append(p)
    if out and out[0][2] is _FREE and len(out) > 1:
        out[1][0] = out[0][0]
        out.pop(0)
    return tuple((lo, hi, role) for lo, hi, role in _merged(out))


def halved(pieces: Sequence[Piece], role: RoleId, low: RoleId, high: RoleId) -> tuple[Piece, ...]:
    """The layout with role's lower half of keys given to low and its upper half to high: a relay's place
    along its chain follows its key (clusters.Roles.place), so each relay goes to the nearer end."""
    half = sum(hi - lo for lo, hi, r in pieces if r == role) / 2.0
    out: list[list] = []
    for lo, hi, r in pieces:
        if r != role:
            out.append([lo, hi, r])
            continue
        cut = min(max(lo + half, lo), hi)
        half -= cut - lo
        out += [p for p in ([lo, cut, low], [cut, hi, high]) if p[1] - p[0] > _EPS]
    return tuple((lo, hi, r) for lo, hi, r in _merged(out))


def came_from(old: Sequence[Piece], new: Sequence[Piece], role: RoleId) -> dict[RoleId, float]:
    """How much of what role holds in new each role held in old (keys it held itself included)."""
    out: dict[RoleId, float] = {}
    for lo, hi, r in new:
        if r != role:
            continue
        for a, b, was in old:
            t = min(hi, b) - max(lo, a)
            if t > _EPS:
                out[was] = out.get(was, 0.0) + t
    return out


def handed(pieces: Sequence[Piece], giver: RoleId, taker: RoleId, amount: float,
           old: Sequence[Piece], source: RoleId) -> tuple[Piece, ...]:
    """The layout with `amount` of giver's keys given to taker, of those that source held in old (giver's own, or
    those it took from source at this survey), from the high end of the largest."""
    cuts = [(max(lo, a), min(hi, b)) for lo, hi, r in pieces if r == giver for a, b, was in old
            if was == source and min(hi, b) - max(lo, a) > _EPS]
    moved: list[tuple[float, float]] = []
    for lo, hi in sorted(cuts, key=lambda c: (c[1] - c[0], c[0]), reverse=True):
        if amount <= _EPS:
            break
        t = min(amount, hi - lo)
        moved.append((hi - t, hi))
        amount -= t
    out: list[list] = []
    for lo, hi, r in pieces:
        inside = sorted((max(lo, a), min(hi, b)) for a, b in moved if r == giver and min(hi, b) - max(lo, a) > _EPS)
        at = lo
        for a, b in inside:
            out += [p for p in ([at, a, r], [a, b, taker]) if p[1] - p[0] > _EPS]
            at = b
        if hi - at > _EPS:
            out.append([at, hi, r])
    return tuple((lo, hi, r) for lo, hi, r in _merged(out))


def end_to_end(shares: dict[RoleId, float]) -> list[tuple[RoleId, float, float]]:
    """(role, start, end) of shares laid end to end in role order, as `fresh` takes them."""
    at, out = 0.0, []
    for role, share in shares.items():
        out.append((role, at, at + share))
        at += share
    return out


def _merged(pieces: list[list]) -> list[list]:
    """Pieces in key order, neighbours of one role (or both free) joined."""
    out: list[list] = []
    for p in sorted(pieces, key=lambda p: p[0]):
        if out and out[-1][2] == p[2] and abs(out[-1][1] - p[0]) <= _EPS:
            out[-1][1] = p[1]
        else:
            out.append(list(p))
    return out


Span = tuple[float, float]  # keys [lo, hi) of MAPs known lost (docs/notes/dynamics.md, "Vacated roles")


def united(*spans: Iterable[Span]) -> tuple[Span, ...]:
    """The union of sets of spans, as sorted disjoint spans: merging what neighbours know is lost."""
    out: list[list[float]] = []
    for lo, hi in sorted(s for group in spans for s in group if s[1] - s[0] > _EPS):
        if out and lo <= out[-1][1] + _EPS:
            out[-1][1] = max(out[-1][1], hi)
        else:
            out.append([lo, hi])
    return tuple((lo, hi) for lo, hi in out)


def squeeze(key: float, lost: Sequence[Span]) -> float:
    """Where key lies on [0, 1) once the lost spans are cut out and the rest stretched over [0, 1).

    Keys in a lost span belong to MAPs that failed (or were taken for failed): cut out, the survivors'
    keys spread over the whole line again, so every role's share is staffed by MAPs that are there.
    A key inside a lost span lands at the span's cut.
    """
    gone = below = 0.0
    for lo, hi in lost:
        gone += hi - lo
        below += min(max(key - lo, 0.0), hi - lo)
    return (key - below) / (1.0 - gone) if gone < 1.0 - _EPS else 0.0


def expand(at: float, lost: Sequence[Span]) -> float:
    """The key that squeeze maps to `at` (the high end of a cut, where a cut lands there)."""
    gone = sum(hi - lo for lo, hi in lost)
    x = at * (1.0 - gone)
    for lo, hi in lost:  # sorted: each span below the point pushes it up by its length
        if x >= lo - _EPS:
            x += hi - lo
    return min(x, 1.0)


def squeezed(pieces: Sequence[Piece], lost: Sequence[Span]) -> tuple[Piece, ...]:
    """A layout on the squeezed line; a role whose keys are all lost keeps an empty piece where they were,
    so that `carry` grows it from its neighbours on the line first."""
    return tuple((squeeze(lo, lost), squeeze(hi, lost), role) for lo, hi, role in pieces)
