"""Airframes by name: what world_sim flies for a scenario's `vehicle: {model: ...}` (docs/vehicle.md).

An airframe is one module here with one class that implements `Airframe`; `AIRFRAMES` names it, and the world
builds the one its scenario names (`start`). A module is imported only when a run flies it, so what an airframe
brings with it (a physics engine, its settings) never reaches a process that does not.
"""
from __future__ import annotations

from importlib import import_module
from importlib.util import find_spec
from typing import TYPE_CHECKING, Optional, Protocol

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from uav_agent.core.params import FlockParams

    from ..vehicle import Vehicle

F64 = NDArray[np.float64]

# name: the module that holds it, and its class
AIRFRAMES = {'ideal': f'{__name__}.ideal:Ideal', 'multirotor': f'{__name__}.multirotor:Multirotor',
             'x500': f'{__name__}.x500:X500'}


class Airframe(Protocol):
    """Every MAP of a run as one vehicle model flies it: the truth of where each is, what it is told of it, the
    power it draws. Rows are the ascending ids of the MAPs still flying; state of every MAP, flying or not, so a
    lost MAP never moves another's draws."""

    # True: the MAPs know where they are and draw no power the records count (the paper's vehicle); False: the
    # world records each MAP's estimate and its power (records.VEHICLE_COLUMNS, ESTIMATE_COLUMNS).
    exact: bool

    def release(self, q: F64, p: F64, centre: tuple[float, float], half_width: float,
                rng: np.random.Generator) -> tuple[F64, F64]:
        """Where and how fast the MAPs start, from the release the scenario drew."""

    def estimate(self, rows: NDArray[np.intp], q: F64) -> F64:
        """Where the MAPs of these rows believe they are (q: the truth)."""

    def power(self, rows: NDArray[np.intp], p: F64) -> F64:
        """Each MAP's propulsion power (W) at velocity p."""

    def traffic(self, truth: F64, told: F64, p: F64, fp: FlockParams) -> Optional[NDArray[np.intp]]:
        """The broadcasts each MAP's traffic receiver passes on, ordered pairs (row, row); None: no receiver."""

    def step(self, rows: NDArray[np.intp], q: F64, p: F64, u: F64) -> tuple[F64, F64]:
        """q and p (truth) one step on under the commanded accelerations u."""


def known(model: object, key: str) -> str:
    """model, when it names an airframe; ValueError naming the key and the airframes there are, when not."""
    if not isinstance(model, str) or model not in AIRFRAMES:
        raise ValueError(f'{key}: must be one of {", ".join(AIRFRAMES)}, got {model!r}')
    return str(model)


def _class(model: str) -> type:
    module, name = AIRFRAMES[model].split(':')
    return getattr(import_module(module), name)


def start(v: Vehicle, n: int, dt: float, rng: np.random.Generator) -> Airframe:
    """The airframe v names, for n MAPs stepped every dt s, drawing from the run's vehicle stream."""
    return _class(v.model)(v, n, dt, rng)


# What an airframe class may say of itself beyond Airframe, each read without building it:
# PROFILE, the values of its `vehicle:` profile measured on it (vehicle.Vehicle's fields; the rest the shipped
# multirotor's); ENVIRONMENT, what its process must have set before anything is imported; NEEDS, the module it
# flies on, and INSTALL, how to install it.
def profile(model: str) -> dict[str, float]:
    return dict(getattr(_class(model), 'PROFILE', {}))


def environment(model: str) -> dict[str, str]:
    return dict(getattr(_class(model), 'ENVIRONMENT', {}))


def missing(model: str) -> Optional[str]:
    """One line that says what to install to fly `model`, or None when nothing is missing."""
    cls = _class(model)
    needs = getattr(cls, 'NEEDS', None)
    if needs is None or find_spec(needs) is not None:
        return None
    install = getattr(cls, 'INSTALL', f'pip install {needs}')
    return f'vehicle {model} flies on {needs}, which is not installed here: {install}'
