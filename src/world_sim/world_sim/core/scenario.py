"""Scenarios: every parameter of a run in one YAML file, checked before anything starts."""
from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Callable, Optional

import yaml

from uav_agent.core import links as channel
from uav_agent.core.checks import bound, did_you_mean, number
from uav_agent.core.links import Links
from uav_agent.core.params import DERIVED, FlockParams
from uav_agent.core.policies import POLICY_VALUES
from uav_agent.core.policies import check as check_flock

from . import vehicle as craft
from .vehicle import Vehicle


class ScenarioError(ValueError):
    """A scenario that cannot run; the message names the offending key."""


@dataclass(frozen=True)
class Cluster:
    center: tuple[float, float]   # centroid of the Gaussian (m)
    spread: float                 # standard deviation per axis (m)
    size: int                     # number of MSDs
    # How the cluster moves (docs/dynamics.md); the defaults are a cluster that stands still all run.
    velocity: tuple[float, float] = (0.0, 0.0)   # drift of the whole cluster (m/s), from `start` on
    waypoints: tuple[tuple[float, float], ...] = ()  # or: a path from `center` through these (m) ...
    speed: float = 0.0                           # ... flown at this speed (m/s), then held at the last
    start: float = 0.0                           # the cluster's MSDs appear at this time (s)
    end: float | None = None                     # and leave at this one (s); None: they stay
    walk: float = 0.0                            # each MSD's own random walk: walk * sqrt(t) m per axis (m/√s)

    @property
    def moves(self) -> bool:
        """Whether anything about the cluster changes during a run."""
        return (self.velocity != (0.0, 0.0) or bool(self.waypoints) or self.start > 0 or self.end is not None
                or self.walk > 0)


@dataclass(frozen=True)
class Scenario:
    name: str
    seed: int
    maps: int
    duration: float                     # simulated time (s)
    dt: float                           # step (s)
    flock: FlockParams
    clusters: tuple[Cluster, ...]
    release_center: tuple[float, float]  # centre of the uniform release square (m)
    release_half_width: float            # half side of that square (m)
    initial_speed: float                 # initial velocity uniform in [-s, s]^2 (m/s)
    # Eq. 2's transmit power (W) and path-loss exponent. Optional and checked > 0: for any positive pair the
    # strongest signal rho*d^-eta in range is the nearest MAP's, so they are recorded, never needed to associate.
    rho: float = 1.0
    eta: float = 3.5
    association: str = '3d'              # MSD-MAP range: '3d' (||y - q|| <= r) or 'horizontal'
    fail_at: float | None = None         # time of the random failure (s)
    fail_fraction: float = 0.0           # fraction of MAPs that fail then
    # What MAPs know of the clusters: 'given' (the clusters as drawn, known before the flight and fixed) or
    # 'online' (re-estimated from where the MSDs are every survey_period s, world_sim/core/survey.py).
    survey: str = 'given'
    survey_period: float = 2.0
    # The radio between MAPs (uav_agent/core/links.py): by default the paper's, every state within r heard at once.
    links: Links = field(default_factory=Links)
    # What the MAPs fly (world_sim/core/vehicle.py): by default the paper's unbounded double integrator.
    vehicle: Vehicle = craft.IDEAL

    def __post_init__(self) -> None:
        # The flock relies on links as long as the channel delivers (links.reach), however the scenario was made,
        # and flies within the vehicle's envelope.
        reach = channel.reach(self.links, self.flock.r)
        if not self.vehicle.ideal:  # and lays its links short of r by what the MAPs' positions may err by
            reach = min(reach or self.flock.r, self.flock.r - self.vehicle.margin)
        derived = {'reach': reach, 'hush': channel.hush(self.links), **self.vehicle.envelope()}
        if any(getattr(self.flock, name) != value for name, value in derived.items()):
            object.__setattr__(self, 'flock', replace(self.flock, **derived))

    @property
    def users_move(self) -> bool:
        return any(c.moves for c in self.clusters)

    @property
    def survey_steps(self) -> int:
        """Steps between surveys, and between the users' positions published and recorded."""
        return max(int(round(self.survey_period / self.dt)), 1)

    @property
    def steps(self) -> int:
        return int(round(self.duration / self.dt))

    def with_overrides(self, **kw: Any) -> 'Scenario':
        """The scenario with some values replaced (None keeps the scenario's), each checked as in a file."""
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        if isinstance(kw.get('vehicle'), str):  # a model by name: the file's own vehicle if it is one, else the profile
            try:
                kw['vehicle'] = self.vehicle if kw['vehicle'] == self.vehicle.model else craft.by_name(kw['vehicle'])
            except ValueError as exc:
                raise ScenarioError(str(exc)) from None
        values.update({k: _OVERRIDABLE[k](v) if k in _OVERRIDABLE else v for k, v in kw.items() if v is not None})
        out = Scenario(**values)
        _check(out)
        return out


_TOP = {'name', 'seed', 'maps', 'duration', 'dt', 'flock', 'policies', 'radio', 'links', 'release', 'users', 'failure',
        'vehicle'}
_RADIO = {'rho', 'eta', 'association'}
_RELEASE = {'center', 'half_width', 'initial_speed'}
_CLUSTER = {'center', 'spread', 'size', 'velocity', 'waypoints', 'speed', 'start', 'end', 'walk'}
_USERS = {'clusters', 'survey', 'survey_period'}
_FAILURE = {'at', 'fraction'}


def _num(where: str, value: Any, *, positive: bool = True, allow_zero: bool = False) -> float:
    try:
        return float(number(value, where, low=0.0 if positive else None, low_open=not allow_zero))
    except ValueError as exc:
        raise ScenarioError(str(exc)) from None


SEED_MAX = 2 ** 63 - 1  # a ROS integer parameter (world_sim's `seed`) holds no more


def _int(where: str, value: Any, *, minimum: int = 1, maximum: Optional[int] = None) -> int:
    try:
        return int(number(value, where, low=minimum, high=maximum, integer=True))
    except ValueError as exc:
        raise ScenarioError(str(exc)) from None


# The values a command line or a node parameter may override: one check for them and for the file's own.
_OVERRIDABLE: dict[str, Callable[[Any], Any]] = {
    'seed': lambda v: _int('seed', v, minimum=0, maximum=SEED_MAX),
    'maps': lambda v: _int('maps', v),
    'duration': lambda v: _num('duration', v),
    'fail_at': lambda v: _num('failure.at', v, allow_zero=True),
    'fail_fraction': lambda v: _num('failure.fraction', v, allow_zero=True),
}


def _section(doc: dict[str, Any], key: str, allowed: set[str], required: bool = True) -> dict[str, Any]:
    if key not in doc:
        if required:
            raise ScenarioError(f'{key}: missing')
        return {}
    sec = doc[key]
    if not isinstance(sec, dict):
        raise ScenarioError(f'{key}: expected a mapping')
    refuse_unknown(sec, allowed, f'{key}.')
    return sec


def refuse_unknown(doc: dict[str, Any], allowed: set[str], prefix: str = '') -> None:
    """ScenarioError for the first key not in `allowed`, with the allowed key it most resembles."""
    unknown = sorted(set(map(str, doc)) - allowed)
    if unknown:
        raise ScenarioError(f'{prefix}{unknown[0]}: unknown key{did_you_mean(unknown[0], sorted(allowed))}')


def _need(sec: dict[str, Any], where: str, key: str) -> Any:
    if key not in sec or sec[key] is None:
        raise ScenarioError(f'{where}.{key}: missing' if where else f'{key}: missing')
    return sec[key]


def _pair(where: str, value: Any) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ScenarioError(f'{where}: expected [x, y], got {value!r}')
    return (_num(f'{where}[0]', value[0], positive=False), _num(f'{where}[1]', value[1], positive=False))


def _cluster(where: str, c: dict[str, Any]) -> Cluster:
    """One entry of users.clusters; every motion key optional, with its unit in the Cluster's comments."""
    waypoints = c.get('waypoints', [])
    if not isinstance(waypoints, list):
        raise ScenarioError(f'{where}.waypoints: expected a list of [x, y], got {waypoints!r}')
    path = tuple(_pair(f'{where}.waypoints[{i}]', w) for i, w in enumerate(waypoints))
    if path and 'velocity' in c:
        raise ScenarioError(f'{where}.waypoints: give either velocity or waypoints, not both')
    if path and 'speed' not in c:
        raise ScenarioError(f'{where}.speed: missing (waypoints are flown at this speed, m/s)')
    start = _num(f'{where}.start', c.get('start', 0.0), allow_zero=True)
    end = _num(f'{where}.end', c['end']) if c.get('end') is not None else None
    if end is not None and end <= start:
        raise ScenarioError(f'{where}.end: must be after start ({start:g} s), got {end:g}')
    return Cluster(_pair(f'{where}.center', _need(c, where, 'center')),
                   _num(f'{where}.spread', _need(c, where, 'spread')),
                   _int(f'{where}.size', _need(c, where, 'size')),
                   velocity=_pair(f'{where}.velocity', c.get('velocity', [0.0, 0.0])),
                   waypoints=path,
                   speed=_num(f'{where}.speed', c['speed']) if path else 0.0,
                   start=start, end=end,
                   walk=_num(f'{where}.walk', c.get('walk', 0.0), allow_zero=True))


def _flock(doc: dict[str, Any]) -> FlockParams:
    """The flock: section's numbers and the policies: section's choices, as one FlockParams."""
    flock_doc = _section(doc, 'flock', {f.name for f in fields(FlockParams)} - set(POLICY_VALUES) - set(DERIVED))
    flock_vals: dict[str, Any] = {}
    for f in fields(FlockParams):
        if f.name in POLICY_VALUES or f.name in DERIVED:
            continue
        raw = _need(flock_doc, 'flock', f.name)
        flock_vals[f.name] = (_int(f'flock.{f.name}', raw, minimum=0) if f.type in ('int', int)
                              else _num(f'flock.{f.name}', raw, positive=False))
    flock_vals.update(_section(doc, 'policies', set(POLICY_VALUES), required=False))
    return FlockParams(**flock_vals)


def _clusters(clusters_doc: Any) -> tuple[Cluster, ...]:
    """users.clusters: one to 63 mappings, each checked key by key."""
    if not isinstance(clusters_doc, list) or not clusters_doc:
        raise ScenarioError('users.clusters: at least one cluster is needed')
    if len(clusters_doc) > 63:
        raise ScenarioError('users.clusters: at most 63 clusters are supported')
    clusters = []
    for i, c in enumerate(clusters_doc):
        where = f'users.clusters[{i}]'
        if not isinstance(c, dict):
            raise ScenarioError(f'{where}: expected a mapping')
        refuse_unknown(c, _CLUSTER, f'{where}.')
        clusters.append(_cluster(where, c))
    return tuple(clusters)


def parse(doc: Any) -> Scenario:
    """Check a scenario document and build the Scenario; raise ScenarioError naming the bad key."""
    if not isinstance(doc, dict):
        raise ScenarioError('scenario: expected a mapping at the top level')
    refuse_unknown(doc, _TOP)
    flock = _flock(doc)
    radio = _section(doc, 'radio', _RADIO)
    release = _section(doc, 'release', _RELEASE)
    users = _section(doc, 'users', _USERS)
    clusters = _clusters(_need(users, 'users', 'clusters'))
    failure = _section(doc, 'failure', _FAILURE, required=False)
    try:
        links = channel.check(Links(**_section(doc, 'links', {f.name for f in fields(Links)}, required=False)))
    except ValueError as exc:
        raise ScenarioError(str(exc)) from None
    try:
        flown = craft.parse(doc['vehicle']) if 'vehicle' in doc else Scenario.vehicle
    except ValueError as exc:
        raise ScenarioError(str(exc)) from None
    survey = users.get('survey', Scenario.survey)
    if survey not in ('given', 'online'):
        raise ScenarioError(f"users.survey: must be 'given' or 'online', got {survey!r}")
    association = _need(radio, 'radio', 'association')
    if association not in ('3d', 'horizontal'):
        raise ScenarioError(f"radio.association: must be '3d' or 'horizontal', got {association!r}")
    scenario = Scenario(
        name=str(doc.get('name', 'unnamed')),
        seed=_OVERRIDABLE['seed'](_need(doc, '', 'seed')),
        maps=_OVERRIDABLE['maps'](_need(doc, '', 'maps')),
        duration=_OVERRIDABLE['duration'](_need(doc, '', 'duration')),
        dt=_num('dt', _need(doc, '', 'dt')),
        flock=flock,
        clusters=clusters,
        release_center=_pair('release.center', _need(release, 'release', 'center')),
        release_half_width=_num('release.half_width', _need(release, 'release', 'half_width')),
        initial_speed=_num('release.initial_speed', _need(release, 'release', 'initial_speed'), allow_zero=True),
        rho=_num('radio.rho', radio.get('rho', Scenario.rho)),
        eta=_num('radio.eta', radio.get('eta', Scenario.eta)),
        association=association,
        fail_at=_OVERRIDABLE['fail_at'](failure['at']) if failure.get('at') is not None else None,
        fail_fraction=_OVERRIDABLE['fail_fraction'](failure.get('fraction', 0.0)),
        survey=survey,
        survey_period=_num('users.survey_period', users.get('survey_period', Scenario.survey_period)),
        links=links,
        vehicle=flown,
    )
    _check(scenario)
    if scenario.fail_at is not None and scenario.fail_at >= scenario.duration:  # a file's own; --duration may cut it
        raise ScenarioError(f'failure.at: {scenario.fail_at:g} s is not before the end of the run '
                            f'(duration {scenario.duration:g} s)')
    return scenario


def _check(s: Scenario) -> None:
    """Relations between keys that each looked fine alone, and the flock parameters as the agent node checks them."""
    try:
        check_flock(s.flock, lambda name: f'{"policies" if name in POLICY_VALUES else "flock"}.{name}')
    except ValueError as exc:
        raise ScenarioError(str(exc)) from None
    if s.fail_fraction > 1.0:
        raise ScenarioError(f'failure.fraction: must be at most 1, got {s.fail_fraction}')
    if s.maps < 1:
        raise ScenarioError(f'maps: must be at least 1, got {s.maps}')
    if s.dt > s.duration:
        raise ScenarioError(f'dt: must not exceed duration ({s.duration}), got {s.dt}')



def to_doc(s: Scenario, policies: bool = True) -> dict[str, Any]:
    """The scenario as a document parse() reads back to an equal Scenario; without `policies` when asked,
    so the file runs whatever policies are the default."""
    flock = s.flock.as_dict()
    doc: dict[str, Any] = {
        'name': s.name, 'seed': s.seed, 'maps': s.maps, 'duration': s.duration, 'dt': s.dt,
        'flock': {k: v for k, v in flock.items() if k not in POLICY_VALUES and k not in DERIVED},
    }
    if policies:
        doc['policies'] = {k: v for k, v in flock.items() if k in POLICY_VALUES}
    doc['radio'] = {'rho': s.rho, 'eta': s.eta, 'association': s.association}
    doc['release'] = {'center': list(s.release_center), 'half_width': s.release_half_width,
                      'initial_speed': s.initial_speed}
    doc['users'] = {'clusters': [_cluster_doc(c) for c in s.clusters]}
    if s.survey != Scenario.survey or s.survey_period != Scenario.survey_period:
        doc['users'].update(survey=s.survey, survey_period=s.survey_period)
    if s.fail_at is not None:
        doc['failure'] = {'at': s.fail_at, 'fraction': s.fail_fraction}
    if s.links != Links():
        doc['links'] = s.links.as_dict()
    doc['vehicle'] = s.vehicle.as_dict()
    return doc


def _cluster_doc(c: Cluster) -> dict[str, Any]:
    """A cluster as its file entry, with only the motion keys it uses (a still cluster reads as before)."""
    out: dict[str, Any] = {'center': list(c.center), 'spread': c.spread, 'size': c.size}
    if c.waypoints:
        out.update(waypoints=[list(w) for w in c.waypoints], speed=c.speed)
    elif c.velocity != (0.0, 0.0):
        out['velocity'] = list(c.velocity)
    if c.start > 0:
        out['start'] = c.start
    if c.end is not None:
        out['end'] = c.end
    if c.walk > 0:
        out['walk'] = c.walk
    return out


class _StrictLoader(yaml.SafeLoader):
    """YAML as safe_load reads it, but a key given twice in one mapping is refused, not the last one kept."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f'{key!r} is given twice in one mapping', key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def read_yaml(path: str | Path, what: str) -> Any:
    """A YAML file's document, or ScenarioError in one line naming the path once (and the line, for bad YAML)."""
    path = Path(path)
    try:
        return yaml.load(path.read_text(), Loader=_StrictLoader)  # noqa: S506 (a SafeLoader)
    except FileNotFoundError:
        raise ScenarioError(f'{path}: no such {what} file') from None
    except (OSError, UnicodeDecodeError) as exc:  # a folder, no permission, a binary file
        why = exc.strerror if isinstance(exc, OSError) else 'not a text file'
        raise ScenarioError(f'{path}: cannot read the {what} ({why})') from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        where = f' at line {mark.line + 1}, column {mark.column + 1}' if mark is not None else ''
        what_went = getattr(exc, 'problem', None) or str(exc).splitlines()[0]
        raise ScenarioError(f'{path}: not valid YAML{where} ({what_went})') from None


def load(path: str | Path) -> Scenario:
    """Read and check a scenario file."""
    doc = read_yaml(path, 'scenario')
    if doc is None:
        raise ScenarioError(f'{path}: the scenario file is empty')
    try:
        return parse(doc)
    except ScenarioError as exc:
        raise ScenarioError(f'{path}: {exc}') from None


@dataclass(frozen=True)
class WorldNodeParams:
    """world_sim's own parameters, beside the scenario overrides; checked by uav_agent.core.checks."""

    scenario: str = ''           # scenario file or shipped name ('' : the default, paper)
    out: str = ''                # run folder for the records ('' : none)
    pid_table: str = ''          # pids.json of the agent processes, for their liveness ('' : none)
    run_info: str = ''           # JSON file published on /run_info, for agents that join from other hosts
    start_timeout: float = field(default=60.0, metadata=bound(low=0.0, low_open=True))  # s to wait for every MAP
    record: bool = False         # wait for a recorder and never outrun it
    marker_period: int = field(default=5, metadata=bound(low=0, integer=True))  # steps between /markers; 0: none
    sync: str = 'lockstep'       # lockstep or realtime
    rate: float = field(default=1.0, metadata=bound(low=0.0, low_open=True))  # realtime: sim s per wall s
    command_ttl: int = field(default=5, metadata=bound(low=1, integer=True))  # realtime: steps a command holds
