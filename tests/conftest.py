"""Shared fixtures: every test that touches DDS gets its own ROS_DOMAIN_ID, so runs never cross-talk."""
from __future__ import annotations

import os
import random

import pytest


@pytest.fixture
def ros_env(monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
    """Environment for ROS processes of one test: a fresh domain, discovery kept on this host."""
    domain = str(random.Random(os.getpid() ^ random.getrandbits(32)).randint(1, 101))
    monkeypatch.setenv('ROS_DOMAIN_ID', domain)
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    return dict(os.environ)


@pytest.fixture
def paper_scenario_path() -> str:
    """The shipped paper scenario, as installed in the workspace."""
    from ament_index_python.packages import get_package_share_directory
    return os.path.join(get_package_share_directory('world_sim'), 'config', 'paper.yaml')
