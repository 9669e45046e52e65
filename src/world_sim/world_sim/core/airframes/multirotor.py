"""The shipped multirotor (`vehicle: {model: multirotor}`, docs/vehicle.md): an autopilot that follows the
commanded acceleration with a first-order lag within a_max and v_max, gusts that push the airframe through its
drag, and a GNSS receiver whose error drifts as a Gauss-Markov process."""
from __future__ import annotations

import math
from typing import Optional

import numpy as np
from numpy.typing import NDArray

from uav_agent.core.envelope import saturate
from uav_agent.core.params import FlockParams

from ..vehicle import Vehicle, power_from_square, release, traffic

F64 = NDArray[np.float64]
# Horizontal drag per unit mass (1/s) through which a gust, the wind less the mean the autopilot's integrator
# holds off, pushes the airframe: the linear drag of a 1-2 kg quadrotor (docs/vehicle.md).
DRAG = 0.3


class Multirotor:
    """A multirotor's state beyond q and p, for every MAP of a run: the acceleration its autopilot delivers,
    its gust and its GNSS error. Each step draws for every MAP, flying or not, from the run's vehicle stream,
    so a lost MAP never moves another's draws."""

    exact = False

    def __init__(self, v: Vehicle, n: int, dt: float, rng: np.random.Generator) -> None:
        self.v, self.dt, self.rng = v, dt, rng
        self.lagged = np.zeros((n, 3))
        self.gust = _stationary(rng, v.wind.gust, n)
        self.shared_sigma = math.sqrt(max(v.gnss.sigma ** 2 - v.gnss.own ** 2, 0.0))
        self.shared = _stationary(rng, self.shared_sigma, 1)  # one error every MAP's receiver has
        self.own = _stationary(rng, v.gnss.own, n)
        angle = math.radians(v.wind.direction)
        self.mean_wind = v.wind.speed * np.array([math.cos(angle), math.sin(angle)])

    def release(self, q: F64, p: F64, centre: tuple[float, float], half_width: float,
                rng: np.random.Generator) -> tuple[F64, F64]:
        """vehicle.release: no two nearer than they keep, none faster than v_max."""
        return release(q, p, self.v, centre, half_width, rng)

    def traffic(self, truth: F64, told: F64, p: F64, fp: FlockParams) -> Optional[NDArray[np.intp]]:
        """vehicle.traffic: the most urgent broadcasts within its receiver's range."""
        return traffic(truth, told, p, self.v, fp)

    def estimate(self, rows: NDArray[np.intp], q: F64) -> F64:
        """Where the MAPs of these rows believe they are: the truth plus their GNSS error (horizontal)."""
        out = q.copy()
        out[:, :2] += self.shared + _of(self.own, rows)
        return out

    def power(self, rows: NDArray[np.intp], p: F64) -> F64:
        """Each MAP's propulsion power (W) at its speed through the air: its ground velocity less the wind where
        it is (power, from the airspeed's square)."""
        air = p[:, :2] - self.mean_wind - _of(self.gust, rows)
        return power_from_square((air * air).sum(axis=1))

    def step(self, rows: NDArray[np.intp], q: F64, p: F64, u: F64) -> tuple[F64, F64]:
        """q and p one step on: the command u (m/s^2) followed with lag tau within a_max, the gust's drag
        added and the sum held within a_max, the speed within v_max; held over the step as physics.integrate
        holds u. Then every MAP's gust and GNSS error move on."""
        v, dt = self.v, self.dt
        follow = 1.0 - math.exp(-dt / v.tau) if v.tau > 0 else 1.0
        lagged = _of(self.lagged, rows)
        lagged += (saturate(u, v.a_max) - lagged) * follow
        if lagged is not self.lagged:
            self.lagged[rows] = lagged
        a = lagged.copy()
        a[:, :2] += DRAG * _of(self.gust, rows)
        a = saturate(a, v.a_max)
        p_next = saturate(p + a * dt, v.v_max)  # a projection: the step's acceleration only shrinks
        a = (p_next - p) / dt
        self.drift()
        return q + p * dt + 0.5 * a * dt * dt, p_next

    def drift(self) -> None:
        """Every MAP's gust and GNSS error one step on."""
        v = self.v
        self.gust, self.shared, self.own = _markov(self.rng, self.dt, (self.gust, v.wind.gust, v.wind.gust_time),
                                                   (self.shared, self.shared_sigma, v.gnss.time),
                                                   (self.own, v.gnss.own, v.gnss.time))


def _of(x: F64, rows: NDArray[np.intp]) -> F64:
    """x's rows of these MAPs (sorted ids of those still flying): x itself while every MAP flies, not a copy."""
    return x if len(rows) == len(x) else x[rows]


def _stationary(rng: np.random.Generator, sigma: float, n: int) -> F64:
    return rng.normal(0.0, sigma, size=(n, 2)) if sigma > 0 else np.zeros((n, 2))


def _markov(rng: np.random.Generator, dt: float, *processes: tuple[F64, float, float]) -> list[F64]:
    """First-order Gauss-Markov processes (x, stationary sigma, correlation time), each one step on (exact). Their
    draws in one call, as many and in the order separate calls would draw them."""
    size = sum(x.size for x, sigma, _ in processes if sigma > 0)
    drawn = rng.normal(size=size) if size else np.zeros(0)  # none drawn where none was: a calm, exact receiver
    out, at = [], 0
    for x, sigma, time in processes:
        if sigma <= 0:
            out.append(x)
            continue
        keep = math.exp(-dt / time)
        out.append(keep * x + sigma * math.sqrt(1.0 - keep * keep) * drawn[at:at + x.size].reshape(x.shape))
        at += x.size
    return out
