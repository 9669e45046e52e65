"""Shared fixtures: every test that touches DDS gets its own ROS_DOMAIN_ID, so runs never cross-talk."""
from __future__ import annotations

import os
from typing import Iterator

import pytest

@pytest.fixture
def ros_env(monkeypatch: pytest.MonkeyPatch) -> Iterator[dict[str, str]]:
    """Environment for ROS processes of one test: a fresh domain, discovery kept on this host, and the
    transports a run's own processes use (domains.ros_env), so that a test's helper in a run's domain
    (a rogue publisher, a graph sampler) meets the run's participants as they meet each other.

    Fresh means the least recently used domain (domains.claim_domain), released at once so that the
    test's `up --domain-id` can claim it: a domain drawn at random could still hold, for the lease's
    20 s, the endpoints of an earlier test's SIGKILLed MAPs."""
    from uav_flock_tools.domains import DomainInUse, claim_domain, ros_env as run_env
    with claim_domain() as domain:
        env = run_env(domain)
    for key in ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE', 'FASTDDS_BUILTIN_TRANSPORTS'):
        monkeypatch.setenv(key, env[key])
    monkeypatch.delenv('ROS_DISCOVERY_SERVER', raising=False)
    yield dict(os.environ)
    try:
        with claim_domain(domain):
            pass  # dated now: the test's processes may have left endpoints behind
    except DomainInUse:
        pass  # something of the test still holds it; its own release dates it


@pytest.fixture
def paper_scenario_path() -> str:
    """The shipped paper scenario, as installed in the workspace."""
    from ament_index_python.packages import get_package_share_directory
    return os.path.join(get_package_share_directory('world_sim'), 'config', 'paper.yaml')


SLOW_FOLDERS = ('ros',)  # tests/ros: real processes over DDS, every one of them
SLOW_FILES = ('test_bootstrap.py',)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """`slow` on whatever starts processes by where it lives; the unit tests that do mark themselves."""
    for item in items:
        path = item.path
        if path.parent.name in SLOW_FOLDERS or path.name in SLOW_FILES:
            item.add_marker(pytest.mark.slow)
