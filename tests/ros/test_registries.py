"""Lockstep `up` equals `sim` byte for byte for whatever is registered: every allocation (policies.ALLOCATIONS)
and every delivery model (links.DELIVERIES), each under the plain channel and under a lossy, late one; and a
delivery model another package registers (an entry point, links.ENTRY_POINTS) flies the same in both."""
from __future__ import annotations

import os
from pathlib import Path

import pytest
import yaml
from helpers.runs import cli
from uav_agent.core.links import DELIVERIES, ENTRY_POINTS
from uav_agent.core.policies import ALLOCATIONS

LOSSY = {'loss': 0.3, 'burst': 3, 'latency': 2, 'ttl': 6}
RUN = ('--maps', '16', '--duration', '5', '--agents-per-process', '8')


@pytest.fixture(scope='module')
def drawn(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A random layout of three clusters, drawn once for every case."""
    out = tmp_path_factory.mktemp('layouts')
    done = cli('layouts', '--count', '1', '--clusters', '3', '--seed', '4', '--out', str(out))
    assert done.returncode == 0, done.stderr
    return yaml.safe_load((out / 'layout-000.yaml').read_text())


def layout(tmp_path: Path, drawn: dict, allocation: str, links: dict) -> Path:
    """The drawn layout, flown with the allocation under the channel."""
    path = tmp_path / 'scenario.yaml'
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump({**drawn, 'policies': {'allocation': allocation}, 'links': links}))
    return path


def same_in_up_and_sim(tmp_path: Path, scenario: Path, env: dict[str, str]) -> bytes:
    distributed = cli('up', '--scenario', str(scenario), *RUN, '--out', str(tmp_path / 'up'), env=env)
    assert distributed.returncode == 0, distributed.stdout + distributed.stderr
    batch = cli('sim', '--scenario', str(scenario), *RUN[:4], '--out', str(tmp_path / 'sim'), env=env)
    assert batch.returncode == 0, batch.stderr
    flown = (tmp_path / 'sim' / 'trajectory.csv').read_bytes()
    assert (tmp_path / 'up' / 'trajectory.csv').read_bytes() == flown
    return flown


@pytest.mark.parametrize('lossy', [False, True], ids=['plain', 'lossy-late'])
@pytest.mark.parametrize('delivery', sorted(DELIVERIES))
@pytest.mark.parametrize('allocation', sorted(ALLOCATIONS))
def test_lockstep_equals_sim_for_every_registered_allocation_and_delivery_model(
        tmp_path: Path, ros_env: dict[str, str], drawn: dict, allocation: str, delivery: str, lossy: bool) -> None:
    links = {'delivery': delivery, **(LOSSY if lossy else {})}
    same_in_up_and_sim(tmp_path, layout(tmp_path, drawn, allocation, links), ros_env)


PLUGIN = '''
"""A delivery model of another package: every state up to half of r, one in two beyond."""
import numpy as np


class Halves:
    def probability(self, links, dist, r):
        return np.where(dist <= 0.5 * r, 1.0, np.where(dist <= r, 0.5, 0.0))

    def reach(self, links, r):
        return r

    def describe(self, links):
        return 'every state within r / 2, half of them beyond'
'''


def test_a_delivery_model_another_package_registers_flies_the_same_in_up_and_sim(
        tmp_path: Path, ros_env: dict[str, str], drawn: dict) -> None:
    """One module and an entry point (docs/links.md, "Adding a delivery model"): `sim`, the agent nodes and the
    world's records all find it by its name, and the run is its own."""
    site = tmp_path / 'site'
    (site / 'halves_delivery-0.dist-info').mkdir(parents=True)
    (site / 'halves_delivery.py').write_text(PLUGIN)
    (site / 'halves_delivery-0.dist-info' / 'METADATA').write_text('Metadata-Version: 2.1\nName: halves-delivery\nVersion: 0\n')
    (site / 'halves_delivery-0.dist-info' / 'entry_points.txt').write_text(f'[{ENTRY_POINTS}]\nhalves = halves_delivery:Halves\n')
    env = {**ros_env, 'PYTHONPATH': os.pathsep.join([str(site), ros_env.get('PYTHONPATH', '')])}
    flown = same_in_up_and_sim(tmp_path / 'halves', layout(tmp_path, drawn, 'demand', {'delivery': 'halves', **LOSSY}), env)
    disc = layout(tmp_path / 'disc', drawn, 'demand', {'delivery': 'disc', **LOSSY})
    assert cli('sim', '--scenario', str(disc), *RUN[:4], '--out', str(tmp_path / 'disc' / 'sim')).returncode == 0
    assert (tmp_path / 'disc' / 'sim' / 'trajectory.csv').read_bytes() != flown, 'the model changes the run'
    unknown = cli('sim', '--scenario', str(tmp_path / 'scenario.yaml'), '--out', str(tmp_path / 'none'), env=ros_env)
    assert unknown.returncode == 2 and "links.delivery: must be one of disc, alpha, got 'halves'" in unknown.stderr, \
        'without the package the name is unknown: one line, exit 2'
