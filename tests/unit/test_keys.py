"""Which keys each role owns (core/allocations/demand/keys.py): the key line with lost keys squeezed out."""
from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from uav_agent.core.allocations.demand import keys


spans = st.lists(st.tuples(st.floats(0, 1), st.floats(0, 0.2)), max_size=4).map(
    lambda pairs: keys.united([(lo, min(lo + w, 1.0)) for lo, w in pairs]))


@settings(max_examples=200, deadline=None)
@given(spans, st.floats(0, 1, exclude_max=True))
def test_squeezing_keeps_the_survivors_order_and_expand_undoes_it(lost: tuple[keys.Span, ...], key: float) -> None:
    if sum(hi - lo for lo, hi in lost) > 0.9 or any(lo - 1e-9 <= key < hi + 1e-9 for lo, hi in lost):
        return
    at = keys.squeeze(key, lost)
    assert 0.0 <= at <= 1.0
    assert math.isclose(keys.expand(at, lost), key, abs_tol=1e-9)
    assert keys.squeeze(min(key + 1e-6, 1.0), lost) >= at
