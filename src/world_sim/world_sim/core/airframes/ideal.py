"""The paper's vehicle (`vehicle: {model: ideal}`): a double integrator with no bound on speed or acceleration,
which knows exactly where it is."""
from __future__ import annotations

from typing import TYPE_CHECKING, Optional

import numpy as np
from numpy.typing import NDArray

from .. import physics

if TYPE_CHECKING:
    from uav_agent.core.params import FlockParams

    from ..vehicle import Vehicle

F64 = NDArray[np.float64]


class Ideal:
    """Eq. 1 integrated as the paper's simulation does (physics.integrate); no draws, no records of its own."""

    exact = True

    def __init__(self, v: Vehicle, n: int, dt: float, rng: np.random.Generator) -> None:
        self.dt = dt

    def release(self, q: F64, p: F64, centre: tuple[float, float], half_width: float,
                rng: np.random.Generator) -> tuple[F64, F64]:
        return q, p

    def estimate(self, rows: NDArray[np.intp], q: F64) -> F64:
        return q

    def power(self, rows: NDArray[np.intp], p: F64) -> F64:
        return np.zeros(len(rows))

    def traffic(self, truth: F64, told: F64, p: F64, fp: FlockParams) -> Optional[NDArray[np.intp]]:
        return None

    def step(self, rows: NDArray[np.intp], q: F64, p: F64, u: F64) -> tuple[F64, F64]:
        return physics.integrate(q, p, u, self.dt)
