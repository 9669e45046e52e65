"""README.md as a new user meets it: every command it shows flies its layout at 1.5 x its floor or more.

Running them all (`tools/readme_check.py`) takes half an hour; what they ask for is checked here in seconds.
"""
from __future__ import annotations

import importlib.util
import shlex
import sys
from pathlib import Path

import pytest

from world_sim.core import layouts
from world_sim.core.scenario import Scenario
from world_sim.shipped import load_scenario

pytestmark = pytest.mark.slow  # the README's runs, simulated

ROOT = Path(__file__).resolve().parents[2]
SPEC = importlib.util.spec_from_file_location('readme_check', ROOT / 'tools' / 'readme_check.py')
assert SPEC is not None and SPEC.loader is not None
readme_check = importlib.util.module_from_spec(SPEC)
sys.modules['readme_check'] = readme_check  # its dataclasses look their module up there
SPEC.loader.exec_module(readme_check)
MARGIN = 1.5  # MAPs over the floor LB that a demo flies with (docs/allocation.md: LB alone splits often)
COPIES = {'runs/my.yaml': 'paper'}  # the README's own scenario starts as a copy of paper.yaml


def runs_of_the_readme() -> list[list[str]]:
    lines = readme_check.commands((ROOT / 'README.md').read_text())
    return [w for w in map(shlex.split, lines) if len(w) > 1 and w[0] == './uav-flock' and w[1] in ('sim', 'up', 'run')]


def scenario_of(words: list[str]) -> Scenario:
    """The scenario a README run flies (its --scenario, the paper's by default), on the vehicle it flies (its
    --vehicle; `run` flies the multirotor unless told)."""
    name = readme_check.option(words, '--scenario')
    vehicle = readme_check.option(words, '--vehicle') or ('multirotor' if words[1] == 'run' else None)
    return load_scenario(COPIES.get(str(name), name or 'paper')).with_overrides(vehicle=vehicle)


def maps_of(words: list[str], scenario: Scenario) -> list[int]:
    """Each MAP count a README run flies (its --maps, a list in a sweep; the scenario's by default)."""
    return [int(n) for n in (readme_check.option(words, '--maps') or str(scenario.maps)).split(',')]


def test_the_readme_shows_runs_of_every_kind() -> None:
    kinds = {w[1] for w in runs_of_the_readme()}
    assert {'sim', 'up'} <= kinds, kinds


@pytest.mark.parametrize('words', runs_of_the_readme(), ids=shlex.join)
def test_every_run_the_readme_shows_flies_above_its_floor(words: list[str]) -> None:
    """Also after a failure it asks for: the MAPs left must still be MARGIN x LB."""
    scenario = scenario_of(words)
    lb = layouts.floor(scenario).total
    counts = maps_of(words, scenario)
    left = 1.0 - float(readme_check.option(words, '--fail-fraction') or 0.0)
    for n in counts:
        assert n * left >= MARGIN * lb, (f'{shlex.join(words)}: {n} MAPs ({n * left:.0f} after the failure) is below '
                                         f'{MARGIN} x LB = {MARGIN * lb:.1f} for {scenario.name}')


# Above this many MAPs a README run is left to tools/readme_check.py and docs/benchmarks.md ("A city": on the ideal
# vehicle five seeds, each covered and connected from about 20 s; on the multirotor covered and still split, as the
# README says): the city's 120 s take 3 min or more of the suite's CPU.
SIMULATED_UP_TO = 200


def settles(words: list[str]) -> bool:
    """Runs of 30 s or more, long enough to have converged (the paper layout connects by about 20 s), of up to
    SIMULATED_UP_TO MAPs."""
    scenario = scenario_of(words)
    return float(readme_check.option(words, '--duration') or scenario.duration) >= 30.0 and \
        max(maps_of(words, scenario)) <= SIMULATED_UP_TO


@pytest.mark.parametrize('words', [w for w in runs_of_the_readme() if settles(w)], ids=shlex.join)
def test_every_run_the_readme_shows_ends_connected_and_covered(words: list[str]) -> None:
    """What the README shows is a network that works: the batch simulator's twin of each run (the same
    scenario, MAPs, seed, duration and failure) ends with one component and R_c >= 95 %. The floor alone
    does not say it: the paper's own Algorithm 2 at 70 MAPs (1.55 x LB) ends in two pieces."""
    from uav_flock_tools.simrun import simulate
    base = scenario_of(words)
    number = lambda key, cast: None if readme_check.option(words, key) is None else cast(readme_check.option(words, key))  # noqa: E731
    for maps in maps_of(words, base):
        for seed in (readme_check.option(words, '--seed') or str(base.seed)).split(','):
            s = base.with_overrides(maps=int(maps), seed=int(seed), duration=number('--duration', float),
                                    fail_at=number('--fail-at', float), fail_fraction=number('--fail-fraction', float))
            result, _ = simulate(s)
            end = result.metrics[-1]
            assert end[5] == 1 and end[2] >= 0.95, (f'{shlex.join(words)} (maps {maps}, seed {seed}) ends in '
                                                    f'{int(end[5])} components, R_c {100 * end[2]:.1f} %')
