"""A study's spec (a YAML file, docs/studies.md) and the runs it names: layouts x seeds x kinds x variants."""
from __future__ import annotations

import argparse
import copy
import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np

from uav_agent.core import ablation
from uav_agent.core.checks import did_you_mean
from world_sim.core import layouts
from world_sim.core.scenario import Scenario, ScenarioError, parse, read_yaml, refuse_unknown, to_doc

from .cases import case, draws, lb_along

KEYS = {'layouts', 'scenario', 'seeds', 'kinds', 'maps', 'duration', 'variants'}
KINDS = ('static', 'drift', 'crossing', 'arrival', 'loss', 'wipeout')
# A variant's list of rules switched off (an ablation), beside its dotted scenario keys. Not `off`: YAML reads
# that word as false.
OFF = 'without'
VALUED = {'drift': 'speed (m/s)', 'loss': 'share of the MAPs that fail'}


class SpecError(ValueError):
    """A spec that names no study: its message is one line, naming the key."""


@dataclass(frozen=True)
class Run:
    """One run of a study: where it sits in the grid, and the scenario it flies (as a document, so that any
    worker reads it the same). key: a hash of the resolved scenario, the kind, its draws and the rules off."""

    key: str
    layout: int
    seed: int
    kind: str
    variant: str
    doc: dict[str, Any]
    draw_seed: int
    off: tuple[str, ...] = ()  # rules the variant switches off (core/ablation.py)

    def scenario(self) -> Scenario:
        return parse(copy.deepcopy(self.doc))


@dataclass(frozen=True)
class Spec:
    layouts: tuple[Scenario, ...]
    seeds: tuple[int, ...]
    kinds: tuple[tuple[str, Optional[float]], ...]
    maps: Optional[float]
    duration: Optional[float]
    variants: dict[str, dict[str, Any]]


def kind_name(kind: str, value: Optional[float]) -> str:
    return kind if value is None else f'{kind}:{value:g}'


def _kind(text: Any) -> tuple[str, Optional[float]]:
    name, _, value = str(text).partition(':')
    if name not in KINDS:
        raise SpecError(f'kinds: {text!r}: expected one of {", ".join(KINDS)} (drift:SPEED, loss:SHARE)')
    if not value:
        return name, None
    if name not in VALUED:
        raise SpecError(f'kinds: {text!r}: {name} takes no value')
    try:
        v = float(value)
    except ValueError:
        raise SpecError(f'kinds: {text!r}: the {VALUED[name]} must be a number') from None
    if not (v > 0 and (name != 'loss' or v < 1)):
        raise SpecError(f'kinds: {text!r}: the {VALUED[name]} must be {"in (0, 1)" if name == "loss" else "positive"}')
    return name, v


def _whole(key: str, value: Any, low: int) -> int:
    """An integer key of the spec, or SpecError naming it (YAML's 2.5, 'three' and true are no counts)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        what = {0: 'a non-negative integer', 1: 'a positive integer'}[low]
        raise SpecError(f'{key}: expected {what}, got {value!r}')
    return value


def _cluster_range(value: Any) -> tuple[int, int]:
    """layouts.clusters as [LO, HI], N, or 'LO-HI' (the form `layouts --clusters` takes)."""
    from ..commands.options import count_range
    if isinstance(value, list) and len(value) == 2:
        lo, hi = (_whole(f'layouts.clusters[{i}]', v, 1) for i, v in enumerate(value))
        if lo <= hi:
            return lo, hi
    elif isinstance(value, (int, str)) and not isinstance(value, bool):
        try:
            return count_range(str(value))
        except argparse.ArgumentTypeError:
            pass
    raise SpecError(f'layouts.clusters: expected [LO, HI], N or "LO-HI" with 1 <= LO <= HI, got {value!r}')


def _layouts(doc: dict[str, Any]) -> tuple[Scenario, ...]:
    from ..layouts import VEHICLE, draw, policy_sets
    from world_sim.core import airframes
    from ..simrun import load_scenario
    if 'layouts' in doc and 'scenario' in doc:
        raise SpecError('layouts: give either layouts (the random-layout generator) or scenario, not both')
    if 'layouts' not in doc and 'scenario' not in doc:
        raise SpecError('layouts: missing: give layouts (the random-layout generator) or scenario (one scenario)')
    if 'scenario' in doc:
        return (load_scenario(str(doc['scenario'])),)
    gen = doc['layouts']
    if not isinstance(gen, dict) or 'count' not in gen:
        raise SpecError('layouts: expected {count: N, clusters: [LO, HI], seed: S}')
    refuse_unknown(gen, {'count', 'clusters', 'seed', 'vehicle'}, 'layouts.')  # ScenarioError: load() names the path
    try:
        airframes.known(gen.get('vehicle', VEHICLE), 'layouts.vehicle')
    except ValueError as e:
        raise SpecError(str(e)) from None
    drawn = draw('paper', _whole('layouts.count', gen['count'], 1), _cluster_range(gen.get('clusters', [3, 6])),
                 _whole('layouts.seed', gen.get('seed', 0), 0), gen.get('vehicle', VEHICLE))
    flock = policy_sets(load_scenario('paper'))['default']
    return tuple(dataclasses.replace(lay, flock=flock) for lay in drawn)


def _variant(name: str, overrides: Any) -> dict[str, Any]:
    """A variant's overrides as dotted keys: `{flock: {c1: 0.4}}` is `{flock.c1: 0.4}`, not a new flock section."""
    if not isinstance(overrides, dict):
        raise SpecError(f'variants: {name}: expected a mapping of dotted.key: value')
    flat: dict[str, Any] = {}
    for key, value in overrides.items():
        if isinstance(value, dict):
            flat.update({f'{key}.{k}': v for k, v in _variant(name, value).items()})
        else:
            flat[str(key)] = value
    return flat


def load(path: Path) -> Spec:
    """Read and check a spec; SpecError (one line) naming what is wrong: the path, then the key."""
    try:
        doc = read_yaml(path, 'spec')
        return _checked(doc)
    except ScenarioError as exc:  # the YAML itself, or the scenario the spec names
        message = str(exc)
        raise SpecError(message if message.startswith(f'{path}:') else f'{path}: {message}') from None
    except SpecError as exc:
        raise SpecError(f'{path}: {exc}') from None


def _checked(doc: Any) -> Spec:
    if not isinstance(doc, dict):
        raise SpecError('expected a mapping of study keys')
    unknown = sorted(set(map(str, doc)) - KEYS)
    if unknown:
        raise SpecError(f'{unknown[0]}: unknown key{did_you_mean(unknown[0], sorted(KEYS))} '
                        f'(keys: {", ".join(sorted(KEYS))})')
    seeds = doc.get('seeds', [0])
    if isinstance(seeds, list):
        seeds = [_whole(f'seeds[{i}]', x, 0) for i, x in enumerate(seeds)]
    else:
        seeds = list(range(_whole('seeds', seeds, 1)))
    kinds = doc.get('kinds', ['static'])
    variants = doc.get('variants') or {'base': {}}
    if not isinstance(kinds, list):
        raise SpecError('kinds: expected a list')
    if not isinstance(variants, dict):
        raise SpecError('variants: expected a mapping of name: {dotted.key: value, ...}')
    for name in variants:
        if not isinstance(name, str):  # YAML reads on, off, yes, no, true, false and numbers as other types
            raise SpecError(f'variants: {name!r} is read as {type(name).__name__}, not a name: quote it')
    variants = {name: _variant(name, v) for name, v in variants.items()}
    for name, v in variants.items():
        off = v.get(OFF, [])
        if not isinstance(off, list) or not all(isinstance(x, str) for x in off):
            raise SpecError(f'variants: {name}: {OFF}: expected a list of rule names')
        if ablation.unknown(off):
            raise SpecError(f'variants: {name}: {OFF}: {", ".join(ablation.unknown(off))}: no such rule '
                            f'(rules: {", ".join(ablation.RULES)})')
    maps, duration = doc.get('maps'), doc.get('duration')
    for key, v in (('maps', maps), ('duration', duration)):
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or v <= 0):
            raise SpecError(f'{key}: expected a positive number')
    if not seeds:
        raise SpecError('seeds: an empty list: give at least one seed')
    if not kinds:
        raise SpecError('kinds: an empty list: give at least one kind')
    return Spec(_layouts(doc), tuple(seeds), tuple(_kind(k) for k in kinds), maps, duration, variants)


def _override(doc: dict[str, Any], dotted: str, value: Any) -> None:
    *path, last = dotted.split('.')
    node = doc
    for part in path:
        node = node.setdefault(part, {})
        if not isinstance(node, dict):
            raise ScenarioError(f'{dotted}: {part} is not a section')
    node[last] = value


def _flown(spec: Spec, lay: Scenario, n: int, seed: int, kind: str, value: Optional[float]) -> tuple[Scenario, int]:
    """The run's scenario before its variant, and the seed of its draws."""
    draw_seed = draws(n, seed, kind, value)
    s = case(kind, lay, seed, np.random.default_rng(draw_seed), value)
    if spec.duration is not None:
        s = dataclasses.replace(s, duration=float(spec.duration))
    if isinstance(spec.maps, int):
        s = dataclasses.replace(s, maps=spec.maps)
    elif spec.maps is not None:
        lb = lb_along(s, s.duration) if kind in ('drift', 'crossing') else layouts.floor(s).total
        s = dataclasses.replace(s, maps=math.ceil(spec.maps * lb))
    return s, draw_seed


def runs(spec: Spec) -> list[Run]:
    """Every run the spec names, in grid order; ScenarioError if a variant sets a key no scenario has."""
    out = []
    for n, lay in enumerate(spec.layouts):
        for seed in spec.seeds:
            for kind, value in spec.kinds:
                base, draw_seed = _flown(spec, lay, n, seed, kind, value)
                for name, overrides in spec.variants.items():
                    doc = to_doc(base)
                    off = tuple(sorted(set(overrides.get(OFF, []))))
                    for dotted, v in overrides.items():
                        if dotted != OFF:
                            _override(doc, str(dotted), v)
                    try:
                        doc = to_doc(parse(copy.deepcopy(doc)))  # checked, and resolved as every worker reads it
                    except ScenarioError as exc:
                        raise SpecError(f'variants: {name}: {exc}') from None
                    label = kind_name(kind, value)
                    what = [doc, label, draw_seed] + ([list(off)] if off else [])  # runs with every rule on: keys as before
                    key = hashlib.sha256(json.dumps(what, sort_keys=True).encode()).hexdigest()[:16]
                    out.append(Run(key, n, seed, label, name, doc, draw_seed, off))
    return out
