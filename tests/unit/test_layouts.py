"""The floor LB and random layouts (world_sim/core/layouts.py)."""
from __future__ import annotations





def test_the_95_percent_radius_constant_is_scipys_quantile_to_the_last_bit() -> None:
    from scipy.stats import chi2

    from world_sim.core.layouts import CHI2_2DOF_95
    assert CHI2_2DOF_95 == chi2.ppf(0.95, 2)
