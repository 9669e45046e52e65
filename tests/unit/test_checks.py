"""One check for a number, whichever door it comes in by: scenario file, node parameter or command line."""
from __future__ import annotations

import argparse
import math

import pytest

from uav_agent.core.checks import check_fields, number
from uav_agent.core.params import AgentNodeParams, FlockParams, check
from uav_flock_tools.commands.options import positive_float
from world_sim.core.scenario import ScenarioError, WorldNodeParams, _num


@pytest.mark.parametrize('bad', [-1.0, 0.0, math.inf, math.nan, 'far', True])
def test_a_positive_value_is_refused_alike_at_every_door(bad: object) -> None:
    said = []
    with pytest.raises(ValueError) as core:
        number(bad, 'x', low=0.0, low_open=True)
    said.append(str(core.value).split(': ', 1)[1])
    with pytest.raises(ScenarioError) as scenario:
        _num('x', bad)
    said.append(str(scenario.value).split(': ', 1)[1])
    with pytest.raises(ValueError) as flock:
        check(FlockParams(r=bad), lambda name: 'x')  # type: ignore[arg-type]
    said.append(str(flock.value).split(': ', 1)[1])
    assert len(set(said)) == 1, said
    if not isinstance(bad, (str, bool)):
        with pytest.raises(argparse.ArgumentTypeError):
            positive_float(str(bad))


def test_node_parameters_are_checked_dataclasses() -> None:
    check_fields(AgentNodeParams())
    check_fields(WorldNodeParams())
    with pytest.raises(ValueError, match='parameter hysteresis: must be non-negative'):
        check_fields(AgentNodeParams(hysteresis=-1.0), lambda n: f'parameter {n}')
    with pytest.raises(ValueError, match='parameter command_ttl: must be a positive integer'):
        check_fields(WorldNodeParams(command_ttl=0), lambda n: f'parameter {n}')


def test_a_number_yaml_reads_as_text_says_how_to_write_it() -> None:
    """`v_max: 1e9` is a string to YAML 1.1 (an exponent needs a dot and a sign): the message says what to write."""
    import yaml
    from uav_agent.core.checks import number
    text = yaml.safe_load('v_max: 1e9')['v_max']
    with pytest.raises(ValueError, match=r"got '1e9' \(YAML reads 1e9 as text: write 1.0e\+09\)") as caught:
        number(text, 'vehicle.v_max')
    assert yaml.safe_load('v: 1.0e+09')['v'] == 1e9, str(caught.value)


def test_a_seed_is_flown_exactly_or_refused() -> None:
    """A seed above 2^53 is not rounded to another one through a float; above a ROS integer's range it is refused."""
    from world_sim.core.scenario import SEED_MAX, ScenarioError, _OVERRIDABLE
    assert _OVERRIDABLE['seed'](2 ** 60 + 1) == 2 ** 60 + 1
    with pytest.raises(ScenarioError, match='seed: must be an integer from 0'):
        _OVERRIDABLE['seed'](SEED_MAX + 1)
