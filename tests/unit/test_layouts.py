"""The floor LB and random layouts (world_sim/core/layouts.py)."""
from __future__ import annotations

import math


def test_the_95_percent_radius_constant_is_scipys_quantile_to_the_last_bit() -> None:
    from scipy.stats import chi2

    from world_sim.core.layouts import CHI2_2DOF_95
    assert CHI2_2DOF_95 == chi2.ppf(0.95, 2)


def test_the_shipped_city_is_as_large_as_it_says() -> None:
    """The city (config/city.yaml): >= 30 clusters and >= 15 000 users, flown by 1.5 x its floor LB MAPs."""
    from world_sim.core.layouts import floor
    from world_sim.shipped import load_scenario
    city = load_scenario('city')
    f = floor(city)
    assert len(city.clusters) >= 30
    assert sum(c.size for c in city.clusters) >= 15_000
    assert city.maps == math.ceil(1.5 * (sum(f.per_cluster) + sum(f.per_edge)))
