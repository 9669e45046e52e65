"""What role each MAP holds under the demand allocation, for tests that follow roles across surveys."""
from __future__ import annotations

from typing import Any

from uav_agent.core.allocations.demand import layout
from uav_agent.core.clusters import ClusterMap, key_of
from uav_agent.core.params import FlockParams


def role_ids(clusters: ClusterMap, n: int, fp: FlockParams, near: bool = False) -> list[Any]:
    """Each of MAPs 0..n-1's role as a cluster id or an edge: what stays the same across surveys (near: rule
    'nearest', as a lagged vehicle lays them out)."""
    roles = layout.roles(clusters, fp.d, near)
    return [[*range(clusters.count), *roles.edges][roles.of(key_of(i))] for i in range(n)]
