"""One way to check a number a user gives, whichever door it comes in by: a scenario file, a command-line
option or a node parameter. A bad value is a ValueError naming where it came from and what it must be;
each door turns that into its own one-line error (ScenarioError, argparse's, the node's exit 2)."""
from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, fields
from typing import Any, Callable, Iterable, Optional


def requirement(low: Optional[float] = None, high: Optional[float] = None, low_open: bool = False,
                integer: bool = False) -> str:
    """What a bound asks for, as it reads after 'must be'."""
    if integer:
        if high is not None:
            return f'an integer from {low:g} to {high:g}'
        return {0: 'a non-negative integer', 1: 'a positive integer'}.get(low, f'an integer >= {low:g}')
    if low is not None and high is not None and not low_open:
        return f'from {low:g} to {high:g}'
    said = []
    if low is not None:
        if low == 0:
            said.append('positive' if low_open else 'non-negative')
        else:
            said.append(f'> {low:g}' if low_open else f'>= {low:g}')
    if high is not None:
        said.append(f'at most {high:g}')
    return ' and '.join(said + ['finite'])


def noun(low: Optional[float] = None, high: Optional[float] = None, low_open: bool = False,
         integer: bool = False) -> str:
    """The same as a noun, as a command line's 'expected ...' reads: 'a positive finite number'."""
    said = requirement(low, high, low_open, integer)
    if integer:
        return said
    if said.startswith('from'):
        return f'a number {said}'
    return f'a {said.replace(" and finite", " finite")} number'


def number(value: Any, where: str, low: Optional[float] = None, high: Optional[float] = None,
           low_open: bool = False, integer: bool = False) -> Any:
    """value as a float (or int), or ValueError('where: ...') if it is no number or out of bounds."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        hint = ''
        if isinstance(value, str):
            try:
                hint = f' (YAML reads {value} as text: write {float(value):.1e})' if math.isfinite(float(value)) else ''
            except ValueError:
                pass
        raise ValueError(f'{where}: expected a number, got {value!r}{hint}')
    if integer and isinstance(value, int):  # exactly: a float of 10^20 would be flown as another number
        if (low is not None and (value <= low if low_open else value < low)) or (high is not None and value > high):
            raise ValueError(f'{where}: must be {requirement(low, high, low_open, integer)}, got {value!r}')
        return value
    v = float(value)
    below = low is not None and (v <= low if low_open else v < low)
    if not math.isfinite(v) or below or (high is not None and v > high) or (integer and v != int(v)):
        raise ValueError(f'{where}: must be {requirement(low, high, low_open, integer)}, got {value!r}')
    return int(v) if integer else v


@dataclass(frozen=True)
class Bound:
    """A field's bounds, kept in the field's metadata: `field(default=..., metadata=bound(low=0.0))`."""

    low: Optional[float] = None
    high: Optional[float] = None
    low_open: bool = False
    integer: bool = False


def bound(**kw: Any) -> dict[str, Bound]:
    return {'bound': Bound(**kw)}


def check_fields(obj: Any, where: Callable[[str], str] = str) -> None:
    """Check every field of a parameter dataclass that carries a bound (metadata=bound(...))."""
    for f in fields(obj):
        b = f.metadata.get('bound')
        if b is not None:
            number(getattr(obj, f.name), where(f.name), b.low, b.high, b.low_open, b.integer)


def _lookalike(name: str) -> str:
    """A name as it reads to the eye: `cl` for c1 and `n0` for nO are typing slips, not other names."""
    return name.lower().translate(str.maketrans('lio', '110'))


def did_you_mean(name: str, names: Iterable[str]) -> str:
    """'; did you mean X?' for the known name that a mistyped one most resembles, or '' if none does."""
    names = list(names)
    near = [n for n in names if _lookalike(n) == _lookalike(name)] or \
        difflib.get_close_matches(name, names, n=1, cutoff=0.5)
    return f'; did you mean {near[0]}?' if near else ''
