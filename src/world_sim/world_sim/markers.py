"""RViz markers of the world (/markers): MAPs coloured by mode, MAP-MAP links, MSDs coloured by their
MAP, cluster centroids. Fixed frame: "world"."""
from __future__ import annotations

import colorsys

import numpy as np
from builtin_interfaces.msg import Duration
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from uav_agent.core.clusters import key_of

from .core.model import Sensed
from .core.physics import UNSERVED, Users

# The mode colours of the plots (tab:blue, tab:orange, tab:green) for M0, M1, M2.
MODE_RGB = ((0.12, 0.47, 0.71), (1.0, 0.50, 0.05), (0.17, 0.63, 0.17))
UNSERVED_RGB = (0.6, 0.6, 0.6)


def map_colour(map_id: int) -> tuple[float, float, float]:
    """A colour of its own for each MAP id, the same in every frame."""
    return colorsys.hsv_to_rgb(key_of(map_id), 0.75, 0.9)  # neighbouring ids, far-apart hues


def _rgba(rgb: tuple[float, float, float], a: float = 1.0) -> ColorRGBA:
    return ColorRGBA(r=float(rgb[0]), g=float(rgb[1]), b=float(rgb[2]), a=a)


def _points(xyz: np.ndarray) -> list[Point]:
    return [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in np.asarray(xyz, dtype=float).reshape(-1, 3)]


def _marker(header: Header, ns: str, kind: int, scale: float) -> Marker:
    return Marker(header=header, ns=ns, id=0, type=kind, action=Marker.ADD, scale=Vector3(x=scale, y=scale, z=scale),
                  pose=Pose(orientation=Quaternion(w=1.0)), lifetime=Duration())


def world_markers(header: Header, sensed: Sensed, modes: np.ndarray, users: Users) -> MarkerArray:
    """One MarkerArray for one step; modes are the MAPs' modes, rows as in sensed."""
    maps = _marker(header, 'maps', Marker.SPHERE_LIST, 3.0)
    maps.points = _points(sensed.q)
    maps.colors = [_rgba(MODE_RGB[int(m)]) for m in modes]

    links = _marker(header, 'links', Marker.LINE_LIST, 0.3)
    pairs = sensed.pairs[sensed.pairs[:, 0] < sensed.pairs[:, 1]]
    links.points = _points(sensed.q[pairs.reshape(-1)])
    links.color = _rgba((0.3, 0.3, 0.3), 0.8)

    msds = _marker(header, 'msds', Marker.POINTS, 0.8)
    msds.points = _points(users.xyz)
    served_by = [int(sensed.ids[row]) if row != UNSERVED else -1 for row in sensed.assoc.tolist()]
    palette = {i: _rgba(map_colour(i)) for i in set(served_by) if i >= 0}
    grey = _rgba(UNSERVED_RGB, 0.6)
    msds.colors = [palette[i] if i >= 0 else grey for i in served_by]

    clusters = _marker(header, 'clusters', Marker.CUBE_LIST, 4.0)
    clusters.points = _points(np.column_stack([users.centroids, np.zeros(len(users.centroids))]))
    clusters.color = _rgba((0.0, 0.0, 0.0))
    return MarkerArray(markers=[maps, links, msds, clusters])
