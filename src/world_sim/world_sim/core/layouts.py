"""Random cluster layouts for judging a policy set on more than one layout, and the MAP floor of each.

A layout is drawn as docs/allocation.md ("Random layouts and their floor") describes: K Gaussian clusters
whose centres lie in a square beyond the release area, far enough apart to be distinct clusters and close
enough that a tree of relays can join them. The floor LB is a geometric count of the MAPs any method needs (coverage discs and relay chains).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from uav_agent.core.clusters import mst_edges

from .scenario import Cluster, Scenario

# The 95 % quantile of the chi-square law with 2 degrees of freedom, scipy.stats.chi2.ppf(0.95, 2) to the last
# bit (a unit test checks it): a literal, because importing scipy.stats for it costs a command 0.5 s at start.
CHI2_2DOF_95 = 5.991464547107979


class LayoutError(ValueError):
    """A layout request no draw can satisfy (e.g. clusters that cannot be placed that far apart)."""


@dataclass(frozen=True)
class LayoutSpec:
    """What a random layout is drawn from. Lengths in m."""

    clusters: tuple[int, int] = (3, 6)       # K drawn uniformly in this closed range
    box: float = 300.0                       # side of the square holding the centres
    offset: tuple[float, float] = (80.0, 120.0)  # gap from the release area's far edge to the square
    min_separation: float = 90.0             # between any two centres
    max_edge: float = 200.0                  # longest allowed MST edge between centres
    spread: tuple[float, float] = (10.0, 18.0)   # sigma per cluster, drawn uniformly
    users: int = 2000                        # MSDs in all, split by random weights in [0.6, 1.4]
    attempts: int = 2000                     # draws before the request is called impossible


@dataclass(frozen=True)
class Floor:
    """The geometric floor of a layout: MAPs per cluster and relays per MST edge (docs/allocation.md)."""

    per_cluster: tuple[int, ...]
    edges: tuple[tuple[int, int], ...]
    per_edge: tuple[int, ...]

    @property
    def total(self) -> int:
        return sum(self.per_cluster) + sum(self.per_edge)


def ground_radius(s: Scenario) -> float:
    """rho: the ground radius a MAP serves at its height under the scenario's association rule."""
    fp = s.flock
    return fp.r if s.association == 'horizontal' else math.sqrt(max(fp.r ** 2 - fp.height ** 2, 0.0))


def disc95(spread: float) -> float:
    """Radius of the disc holding 95 % of an isotropic 2-D Gaussian's mass: sigma * sqrt(chi2_2(0.95))."""
    return spread * math.sqrt(CHI2_2DOF_95)


def floor(s: Scenario) -> Floor:
    """LB: per cluster ceil(pi R95^2 / (0.8 pi rho^2)); per MST edge ceil((L - 2 sa - 2 sb) / r)."""
    rho, r = ground_radius(s), s.flock.r
    per_cluster = tuple(math.ceil(disc95(c.spread) ** 2 / (0.8 * rho ** 2)) for c in s.clusters)
    xy = np.array([c.center for c in s.clusters], dtype=float)
    edges = mst_edges(xy)
    per_edge = []
    for a, b in edges:
        gap = float(np.linalg.norm(xy[a] - xy[b])) - 2 * s.clusters[a].spread - 2 * s.clusters[b].spread
        per_edge.append(max(0, math.ceil(gap / r)))
    return Floor(per_cluster, tuple(edges), tuple(per_edge))


def draw(base: Scenario, spec: LayoutSpec, rng: np.random.Generator) -> Scenario:
    """A scenario like base with a random cluster layout; LayoutError when spec cannot be met."""
    lo, hi = spec.clusters
    if lo < 1 or hi < lo:
        raise LayoutError(f'clusters: need 1 <= low <= high, got {lo}-{hi}')
    k = int(rng.integers(lo, hi + 1))
    # The release square's far edge in +x; the centres' square lies an offset beyond it, centred on its y.
    far_x = base.release_center[0] + base.release_half_width
    for _ in range(spec.attempts):
        x0 = far_x + rng.uniform(*spec.offset)
        y0 = base.release_center[1] - spec.box / 2
        centres = _place(k, x0, y0, spec, rng)
        if centres is None:
            continue
        xy = np.array(centres)
        if any(np.linalg.norm(xy[a] - xy[b]) > spec.max_edge for a, b in mst_edges(xy)):
            continue
        weights = rng.uniform(0.6, 1.4, size=k)
        sizes = np.floor(spec.users * weights / weights.sum()).astype(int)
        sizes[: spec.users - sizes.sum()] += 1
        spreads = rng.uniform(*spec.spread, size=k)
        clusters = tuple(Cluster((round(float(x), 1), round(float(y), 1)), round(float(sd), 1), int(n))
                         for (x, y), sd, n in zip(xy, spreads, sizes))
        return replace(base, clusters=clusters)
    raise LayoutError(f'cannot place {k} clusters {spec.min_separation:g} m apart in a {spec.box:g} m square '
                      f'with no MST edge over {spec.max_edge:g} m ({spec.attempts} draws tried)')


def _place(k: int, x0: float, y0: float, spec: LayoutSpec, rng: np.random.Generator) -> list[tuple[float, float]] | None:
    """k centres in the square, pairwise at least min_separation apart, by sequential rejection."""
    centres: list[tuple[float, float]] = []
    for _ in range(k):
        for _ in range(200):
            c = (x0 + rng.uniform(0, spec.box), y0 + rng.uniform(0, spec.box))
            if all(math.dist(c, o) >= spec.min_separation for o in centres):
                centres.append(c)
                break
        else:
            return None
    return centres
