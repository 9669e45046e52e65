"""Shared fixtures: every test that touches DDS gets its own ROS_DOMAIN_ID, so runs never cross-talk."""
from __future__ import annotations

import os
import random

import pytest


@pytest.fixture
def ros_env(monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
    """Environment for ROS processes of one test: a fresh domain, discovery kept on this host, and the
    transports a run's own processes use (domains.ros_env), so that a test's helper in a run's domain
    (a rogue publisher, a graph sampler) meets the run's participants as they meet each other."""
    from uav_flock_tools.domains import ros_env as run_env
    env = run_env(random.Random(os.getpid() ^ random.getrandbits(32)).randint(1, 101))
    for key in ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE', 'FASTDDS_BUILTIN_TRANSPORTS'):
        monkeypatch.setenv(key, env[key])
    monkeypatch.delenv('ROS_DISCOVERY_SERVER', raising=False)
    return dict(os.environ)


@pytest.fixture
def paper_scenario_path() -> str:
    """The shipped paper scenario, as installed in the workspace."""
    from ament_index_python.packages import get_package_share_directory
    return os.path.join(get_package_share_directory('world_sim'), 'config', 'paper.yaml')
