"""Users that move (world_sim/core/crowd.py and the scenario's motion keys): waypoints, still crowds, bad keys."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from uav_flock_tools.batch import BatchSimulator
from world_sim.core.crowd import center_at
from world_sim.core.scenario import Cluster, ScenarioError, parse


def test_a_cluster_follows_its_waypoints_then_holds() -> None:
    c = Cluster((0.0, 0.0), 10.0, 100, waypoints=((30.0, 0.0), (30.0, 40.0)), speed=2.0, start=5.0)
    assert np.allclose(center_at(c, 3.0), [0.0, 0.0]), 'still before it starts'
    assert np.allclose(center_at(c, 5.0 + 10.0), [20.0, 0.0])
    assert np.allclose(center_at(c, 5.0 + 25.0), [30.0, 20.0])
    assert np.allclose(center_at(c, 500.0), [30.0, 40.0])


def test_users_that_stand_still_are_never_moved_or_resurveyed(paper_scenario_path: str) -> None:
    sim = BatchSimulator(parse(yaml.safe_load(Path(paper_scenario_path).read_text())).with_overrides(duration=3.0))
    before = sim.world.users
    sim.run()
    assert sim.world.users is before and sim.world.clusters_version == 0 and sim.result().motion is None


@pytest.mark.parametrize('edit, key', [
    (lambda c: c.__setitem__('velocity', [1.0]), 'users.clusters[0].velocity'),
    (lambda c: c.__setitem__('waypoints', [[1.0, 2.0]]), 'users.clusters[0].speed'),
    (lambda c: c.update(waypoints=[[1.0, 2.0]], speed=2.0, velocity=[1.0, 0.0]), 'users.clusters[0].waypoints'),
    (lambda c: c.__setitem__('speed', -2.0) or c.__setitem__('waypoints', [[0, 0]]), 'users.clusters[0].speed'),
    (lambda c: c.update(start=10.0, end=5.0), 'users.clusters[0].end'),
    (lambda c: c.__setitem__('walk', -0.5), 'users.clusters[0].walk'),
    (lambda c: c.__setitem__('start', 'soon'), 'users.clusters[0].start'),
])
def test_bad_motion_keys_name_the_key(paper_scenario_path: str, edit: Any, key: str) -> None:
    doc = yaml.safe_load(Path(paper_scenario_path).read_text())
    edit(doc['users']['clusters'][0])
    with pytest.raises(ScenarioError) as err:
        parse(doc)
    assert str(err.value).startswith(key + ':'), str(err.value)


def test_survey_mode_is_checked(paper_scenario_path: str) -> None:
    doc = yaml.safe_load(Path(paper_scenario_path).read_text())
    doc['users']['survey'] = 'sometimes'
    with pytest.raises(ScenarioError, match=r'^users.survey:'):
        parse(doc)
