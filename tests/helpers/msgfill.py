"""Fill any rosidl message with varied, reproducible values, so a round trip checks every field."""
from __future__ import annotations

import importlib
import random
import re
from typing import Any

_INT_RANGES = {
    'int8': (-128, 127), 'uint8': (0, 255), 'int16': (-2**15, 2**15 - 1), 'uint16': (0, 2**16 - 1),
    'int32': (-2**31, 2**31 - 1), 'uint32': (0, 2**32 - 1), 'int64': (-2**63, 2**63 - 1),
    'uint64': (0, 2**64 - 1), 'octet': (0, 255), 'char': (0, 255), 'byte': (0, 255),
}


def msg_class(type_name: str) -> type:
    """'geometry_msgs/Point' -> the class."""
    pkg, name = type_name.split('/')[0], type_name.split('/')[-1]
    return getattr(importlib.import_module(f'{pkg}.msg'), name)


def _value(kind: str, rng: random.Random) -> Any:
    seq = re.fullmatch(r'sequence<(.+?)(?:, (\d+))?>', kind) or re.fullmatch(r'(.+)\[(\d+)\]', kind)
    if seq:  # a fixed array, a bounded sequence (up to its bound) or an unbounded one
        n = int(seq.group(2)) if kind.endswith(']') else rng.randint(1, int(seq.group(2) or 4))
        return [_value(seq.group(1), rng) for _ in range(n)]
    if kind in _INT_RANGES:
        lo, hi = _INT_RANGES[kind]
        return rng.randint(lo, hi)
    if kind in ('float', 'double', 'float32', 'float64'):
        return float(rng.randint(-10**6, 10**6)) / 64.0  # exact in float32 and float64
    if kind == 'boolean':
        return rng.random() < 0.5
    if kind.startswith('string') or kind.startswith('wstring'):
        return ''.join(rng.choice('abcxyz_019') for _ in range(rng.randint(0, 12)))
    return fill(msg_class(kind)(), rng)


def fill(msg: Any, rng: random.Random) -> Any:
    """Set every field of msg (recursively) to a random value of its type."""
    for field, kind in msg.get_fields_and_field_types().items():
        setattr(msg, field, _value(kind, rng))
    return msg


def diff(a: Any, b: Any, prefix: str = '') -> list[str]:
    """Field paths where two messages differ (empty if equal)."""
    if not hasattr(a, 'get_fields_and_field_types'):
        if isinstance(a, (list, tuple)) or hasattr(a, 'tolist'):
            a, b = list(a), list(b)
            if len(a) != len(b):
                return [f'{prefix}: length {len(a)} != {len(b)}']
            return [d for i, (x, y) in enumerate(zip(a, b)) for d in diff(x, y, f'{prefix}[{i}]')]
        return [] if a == b else [f'{prefix}: {a!r} != {b!r}']
    out: list[str] = []
    for field in a.get_fields_and_field_types():
        out += diff(getattr(a, field), getattr(b, field), f'{prefix}.{field}' if prefix else field)
    return out
