"""The vehicle a MAP flies (scenario `vehicle:`, docs/vehicle.md): the paper's double integrator, or a multirotor
whose autopilot follows the commanded acceleration with a lag, within its speed and acceleration, in gusty
wind, knowing its own position through a GNSS receiver that errs. The world owns it: the truth, the estimate
the MAP is told, and the power it draws (Zeng, Xu and Zhang 2019).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from uav_agent.core import safety
from uav_agent.core.checks import number
from uav_agent.core.envelope import braking_room, lengths, saturate
from uav_agent.core.params import FlockParams

from . import airframes

F64 = NDArray[np.float64]
GNSS_MARGIN = 3.0  # sigma of the difference of two MAPs' own GNSS errors that a MAP keeps beyond separation ...
KEEP_SLACK = 1.0   # ... and this much more (m): what a step and the lag let a braking pair close further


@dataclass(frozen=True)
class Wind:
    speed: float = 5.0          # mean wind (m/s)
    direction: float = 0.0      # where it blows towards, degrees anticlockwise from +x
    gust: float = 1.5           # sigma of each horizontal gust component (m/s), a Gauss-Markov process ...
    gust_time: float = 5.0      # ... of this correlation time (s)


@dataclass(frozen=True)
class Gnss:
    sigma: float = 1.5          # sigma of each horizontal component of a MAP's position error (m), Gauss-Markov ...
    time: float = 60.0          # ... of this correlation time (s)
    # ... of which this much (sigma, m) is the receiver's own (multipath, noise); the rest (atmosphere, orbits,
    # clocks) every receiver of the area shares, and it does not move one MAP relative to another.
    own: float = 0.5


@dataclass(frozen=True)
class Vehicle:
    """The scenario's `vehicle:` section; the defaults are the shipped multirotor profile (docs/vehicle.md)."""

    model: str = 'multirotor'
    v_max: float = 15.0         # speed over the ground (m/s)
    a_max: float = 4.0          # acceleration over the ground, wind included (m/s^2)
    tau: float = 0.3            # lag of the autopilot's acceleration behind the command (s)
    separation: float = 3.0     # the least distance two MAPs may come to (m)
    cruise: float = 0.0         # the speed the MAPs plan to fly at most (m/s; 0: v_max), docs/vehicle.md
    traffic: float = 100.0      # range (m) at which a MAP receives the others' position broadcasts (0: none)
    wind: Wind = field(default_factory=Wind)
    gnss: Gnss = field(default_factory=Gnss)

    @property
    def ideal(self) -> bool:
        return self.model == 'ideal'

    @property
    def margin(self) -> float:
        """How far (m) two MAPs' true distance may differ from what they plan it to be: their own GNSS errors
        (GNSS_MARGIN sigma of the difference) and what a step and the lag let them drift (KEEP_SLACK)."""
        return 0.0 if self.ideal else KEEP_SLACK + GNSS_MARGIN * math.sqrt(2.0) * self.gnss.own

    @property
    def keep(self) -> float:
        """The distance (m) the MAPs keep: separation and its margin (what rule 'keep' is told as FlockParams.keep)."""
        return self.separation + self.margin

    def envelope(self) -> dict[str, float]:
        """What the MAPs are told (FlockParams' ENVELOPE): zeros on the paper's vehicle."""
        if self.ideal:
            return {'v_max': 0.0, 'a_max': 0.0, 'tau': 0.0, 'keep': 0.0, 'traffic': 0.0}
        return {'v_max': min(self.cruise or self.v_max, self.v_max), 'a_max': self.a_max, 'tau': self.tau,
                'keep': self.keep, 'traffic': self.traffic}

    def describe(self) -> str:
        """The vehicle in words, as `sim` and `up` state it at the start of a run."""
        if self.ideal:
            return "ideal: the paper's double integrator, unbounded"
        w, g = self.wind, self.gnss
        cruise = f', cruising at {self.envelope()["v_max"]:g}' if self.cruise else ''
        hears = f'traffic within {self.traffic:g} m' if self.traffic else 'no traffic receiver'
        return (f'{self.model}: {self.v_max:g} m/s{cruise}, {self.a_max:g} m/s^2, lag {self.tau:g} s, keeps '
                f'{self.envelope()["keep"]:.1f} m (separation {self.separation:g} m, {hears}); wind {w.speed:g} m/s towards '
                f'{w.direction:g} deg, gusts {w.gust:g} m/s over {w.gust_time:g} s; GNSS error {g.sigma:g} m '
                f'({g.own:g} m its own) over {g.time:g} s')

    def as_dict(self) -> dict[str, Any]:
        if self.ideal:
            return {'model': 'ideal'}
        out: dict[str, Any] = {f.name: getattr(self, f.name) for f in fields(self)}
        out['wind'] = {f.name: getattr(self.wind, f.name) for f in fields(Wind)}
        out['gnss'] = {f.name: getattr(self.gnss, f.name) for f in fields(Gnss)}
        return out


IDEAL = Vehicle(model='ideal')
MULTIROTOR = Vehicle()


def by_name(model: str) -> Vehicle:
    """The vehicle a model's name stands for on a command line: the ideal one, or the shipped profile flown on
    that airframe."""
    airframes.known(model, 'vehicle')
    return IDEAL if model == 'ideal' else replace(MULTIROTOR, model=model, **airframes.profile(model))


def parse(doc: Any, where: str = 'vehicle') -> Vehicle:
    """The `vehicle:` section: `model` and any key of the multirotor (the shipped profile's values for the rest).
    ValueError naming the key for anything a vehicle cannot be."""
    from .scenario import refuse_unknown
    if not isinstance(doc, dict):
        raise ValueError(f'{where}: expected a mapping')
    model = airframes.known(doc.get('model', 'multirotor'), f'{where}.model')
    if model == 'ideal':
        refuse_unknown(doc, {'model'}, f'{where}.')
        return IDEAL
    refuse_unknown(doc, {f.name for f in fields(Vehicle)}, f'{where}.')
    values: dict[str, Any] = {'model': model, **airframes.profile(model)}
    for name, low_open in (('v_max', True), ('a_max', True), ('tau', False), ('separation', False), ('cruise', False),
                           ('traffic', False)):
        if name in doc:
            values[name] = float(number(doc[name], f'{where}.{name}', low=0.0, low_open=low_open))
    values['wind'] = _part(doc.get('wind', {}), Wind, f'{where}.wind', ('speed', 'gust'))
    values['gnss'] = gnss = _part(doc.get('gnss', {}), Gnss, f'{where}.gnss', ('sigma', 'own'))
    if gnss.own > gnss.sigma:
        raise ValueError(f'{where}.gnss.own: part of sigma ({gnss.sigma:g} m), must not exceed it, got {gnss.own:g}')
    return Vehicle(**values)


def _part(doc: Any, kind: type, where: str, zero_ok: tuple[str, ...]) -> Any:
    from .scenario import refuse_unknown
    if not isinstance(doc, dict):
        raise ValueError(f'{where}: expected a mapping')
    refuse_unknown(doc, {f.name for f in fields(kind)}, f'{where}.')
    values = {}
    for name, value in doc.items():
        if name == 'direction':
            values[name] = float(number(value, f'{where}.{name}'))
        else:
            values[name] = float(number(value, f'{where}.{name}', low=0.0, low_open=name not in zero_ok))
    return kind(**values)


REACH_SLACK = 1e-6  # m
FEW = 8  # MAPs drawn again that a release measures against all by hand, quicker than a tree
TRAFFIC_MOST = 8  # the most broadcasts a MAP's traffic receiver passes on each step: the most urgent


def traffic(truth: F64, told: F64, p: F64, v: Vehicle, fp: FlockParams | None = None) -> NDArray[np.intp] | None:
    """Ordered pairs (i, j) of rows, sorted by i then j: the broadcasts (position as j's GNSS tells it, velocity)
    that MAP i's traffic receiver passes on, of those within v.traffic m (truth). Only those rule 'keep' acts on,
    whose room left once MAP i had braked to a stop along the line between them is below keep (links it
    closes on faster than it could stop keep m short, or nearer than keep): the rule adds nothing for the
    others. Of those, the TRAFFIC_MOST with least room. None: no receiver. fp: what the MAPs fly; under the
    safety filter (FlockParams.safety), the pairs whose barrier can bind (safety.binding), least budget first."""
    if v.ideal or v.traffic <= 0:
        return None
    if len(truth) < 2:
        return np.zeros((0, 2), dtype=np.intp)
    keep = v.keep
    # No two MAPs close faster than the two that fly most off the formation's mean velocity, together: a formation
    # in transit flies together at v_max, and its pairs are sought as near as its settled ones (REACH_SLACK: the
    # bound computed in floating point).
    off = p - p.sum(axis=0) / len(p)  # about the mean velocity: any point bounds it, the mean best
    off = np.sqrt(np.partition(np.einsum('ij,ij->i', off, off), len(off) - 2)[-2:])
    filt = fp if fp is not None and fp.safety == 'filter' else None  # the MAPs' safety filter, if they fly it
    if filt is not None:  # the pairs whose barrier can bind
        reach = safety.reach(float(off[0] + off[1]), filt) + REACH_SLACK
    else:  # rule 'keep': the pairs it brakes on
        reach = keep + braking_room(float(off[0] + off[1]), v.a_max, v.tau) + REACH_SLACK  # no pair farther acts
    near = reach < v.traffic  # the same pairs, found among fewer: those within range (truth) kept once they act
    tree = cKDTree(told if near else truth, balanced_tree=False, compact_nodes=False)  # built each step: built quick
    pairs = tree.query_pairs(reach if near else v.traffic, output_type='ndarray')
    i, j = pairs[:, 0], pairs[:, 1]
    dq, dp = told[j] - told[i], p[j] - p[i]
    if filt is not None:  # the barrier's budget, the same both ways: least is most urgent
        room = safety.budget(dq, dp, filt)
        acting = np.flatnonzero(room < filt.a_max)  # safety.binding, from the budget just computed
    else:
        dist = np.maximum(np.sqrt(np.einsum('ij,ij->i', dq, dq)), 1e-9)
        closing = np.maximum(-np.einsum('ij,ij->i', dp, dq) / dist, 0.0)  # the same both ways
        room = dist - braking_room(closing, v.a_max, v.tau)
        acting = np.flatnonzero(room < keep)
    if len(acting) == 0:  # most steps: no MAP needs to brake for another
        return np.zeros((0, 2), dtype=np.intp)
    pairs, room = pairs[acting], room[acting]
    if near:
        heard = lengths(truth[pairs[:, 1]] - truth[pairs[:, 0]]) <= v.traffic
        pairs, room = pairs[heard], room[heard]
    both, room = np.concatenate([pairs, pairs[:, ::-1]]).astype(np.intp), np.concatenate([room, room])
    both = both[np.lexsort((both[:, 1], room, both[:, 0]))]
    first = np.searchsorted(both[:, 0], both[:, 0], side='left')
    chosen = both[np.arange(len(both)) - first < TRAFFIC_MOST]
    return chosen[np.lexsort((chosen[:, 1], chosen[:, 0]))]


def release(q: F64, p: F64, v: Vehicle, centre: tuple[float, float], half_width: float,
            rng: np.random.Generator) -> tuple[F64, F64]:
    """The release of a multirotor: no two MAPs nearer than the distance they keep (separation and its margins,
    Vehicle.envelope; a MAP too near one before it is drawn again in the square, widened if too small (roomy),
    from the vehicle's stream), none faster than v_max. The release stream's draws stay as they were, so both vehicles leave the same seed's MAPs
    alike wherever those are far enough apart."""
    q, p = q.copy(), saturate(p.copy(), v.v_max)
    apart = v.keep
    half_width = roomy(len(q), half_width, apart)
    again = np.arange(len(q))  # at first, every MAP
    for _ in range(10_000):
        near = _too_near(q[:, :2], again, apart)
        if len(near) == 0:
            return q, p
        again = np.unique(np.max(near, axis=1))
        q[again, :2] = np.asarray(centre) + rng.uniform(-half_width, half_width, size=(len(again), 2))
    raise ValueError(f'vehicle.separation: {apart:g} m (with its margins) could not be kept among {len(q)} MAPs '
                     f'released in a square of side {2 * half_width:g} m')


def _too_near(xy: F64, rows: NDArray[np.intp], apart: float) -> NDArray[np.intp]:
    """The pairs (i, j), i of `rows`, j any other MAP, no farther apart than `apart`. After the
    first round of a release only a MAP just drawn again can be too near one: the others were apart and have not
    moved. The pairs query_pairs on every MAP would find: a few hundred rounds at a thousand MAPs in 0.6 of the time."""
    if len(rows) == len(xy):
        return cKDTree(xy).query_pairs(apart, output_type='ndarray')
    if len(rows) <= FEW:
        d = xy[rows, None, :] - xy[None, :, :]
        i, j = np.nonzero(np.einsum('ijk,ijk->ij', d, d) <= apart * apart)
        i = rows[i]
    else:
        hits = cKDTree(xy, balanced_tree=False, compact_nodes=False).query_ball_point(xy[rows], apart,
                                                                                       return_sorted=False)
        i, j = np.repeat(rows, [len(h) for h in hits]), np.concatenate(hits).astype(np.intp)
    return np.stack([i[i != j], j[i != j]], axis=1)


def roomy(maps: int, half_width: float, apart: float) -> float:
    """The half width of a release square that holds `maps` MAPs `apart` m apart with room to draw them at random
    (discs of diameter `apart` covering at most 40 % of it; random sequential packing jams near 55 %): the
    scenario's, or wider about the same centre when that is too small."""
    need = math.sqrt(maps * math.pi * (apart / 2.0) ** 2 / 0.4) / 2.0 - apart / 2.0
    return max(half_width, need)


# Zeng, Xu and Zhang (IEEE TWC 2019), eq. 12 with their Table I: blade profile and induced power in hover (W), the
# rotor's tip speed (m/s), the mean induced velocity in hover (m/s), fuselage drag ratio, air density (kg/m^3),
# rotor solidity and disc area (m^2).
P0, PI, U_TIP, V0, D0, RHO, SOLIDITY, AREA = 79.86, 88.63, 120.0, 4.03, 0.6, 1.225, 0.05, 0.503


def power(airspeed: F64) -> F64:
    """Propulsion power (W) of a rotary-wing UAV in level flight at this airspeed (m/s): eq. 12 of Zeng et al."""
    v = np.asarray(airspeed, dtype=float)
    return power_from_square(v * v)


def power_from_square(v2: F64) -> F64:
    """Eq. 12 of Zeng et al. from the airspeed's square (m^2/s^2): blade profile, induced and parasite power."""
    blade = P0 + (3.0 * P0 / U_TIP ** 2) * v2
    induced = PI * np.sqrt(np.sqrt(1.0 + v2 * v2 * (1.0 / (4.0 * V0 ** 4))) - v2 * (1.0 / (2.0 * V0 ** 2)))
    parasite = (0.5 * D0 * RHO * SOLIDITY * AREA) * v2 * np.sqrt(v2)
    return blade + induced + parasite


HOVER = float(power(0.0))  # W: 168.49


def least_time(distance: float, v_max: float, a_max: float) -> float:
    """The least time from rest to rest over `distance` within v_max and a_max (s)."""
    if distance <= 0:
        return 0.0
    if distance >= v_max ** 2 / a_max:
        return distance / v_max + v_max / a_max
    return 2.0 * math.sqrt(distance / a_max)
