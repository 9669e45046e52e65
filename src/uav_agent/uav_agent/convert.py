"""Messages to core values and back: the one place where uav_flock_msgs meet numpy."""
from __future__ import annotations

import math
from typing import Iterable

import numpy as np
from geometry_msgs.msg import Point, Vector3
from uav_flock_msgs.msg import AgentState

from .core.modes import Told, ids_of, mask_of


def point(v: np.ndarray) -> Point:
    return Point(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def vector(v: np.ndarray) -> Vector3:
    return Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def xyz(m: Point | Vector3) -> np.ndarray:
    return np.array([m.x, m.y, m.z])


def finite(*values: Point | Vector3 | float) -> bool:
    """True if every number (or every coordinate of a Point/Vector3) is finite."""
    for v in values:
        parts: Iterable[float] = (v.x, v.y, v.z) if hasattr(v, 'x') else (v,)
        if not all(math.isfinite(float(c)) for c in parts):
            return False
    return True


def achieved_mask(msg: AgentState) -> int:
    return mask_of(msg.achieved_goals)


def achieved_list(mask: int) -> list[int]:
    return ids_of(mask)


def told(msg: AgentState) -> Told:
    """The role a neighbour's state states: mode, goal and bridge (None unless it names two clusters)."""
    bridge = tuple(int(c) for c in msg.bridge)
    return Told(int(msg.mode), int(msg.goal), bridge if len(bridge) == 2 else None)
