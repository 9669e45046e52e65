"""Scenario files by path or by the name of one shipped with world_sim (share/world_sim/config/<name>.yaml)."""
from __future__ import annotations

from pathlib import Path

from world_sim.core.scenario import Scenario, ScenarioError, load

DEFAULT = 'paper'  # the paper's scenario, what a world started without one runs


def resolve(name_or_path: str) -> Path:
    """A scenario file path, or the file of the shipped scenario of that name (e.g. 'paper')."""
    path = Path(name_or_path)
    if path.suffix in ('.yaml', '.yml') or path.exists():
        return path
    from ament_index_python.packages import get_package_share_directory
    shipped = Path(get_package_share_directory('world_sim')) / 'config' / f'{name_or_path}.yaml'
    if not shipped.exists():
        choices = sorted(p.stem for p in shipped.parent.glob('*.yaml'))
        raise ScenarioError(f'no scenario file {name_or_path!r} and no shipped scenario of that name '
                            f'(shipped: {", ".join(choices)})')
    return shipped


def load_scenario(name_or_path: str) -> Scenario:
    """Read and check a scenario given by path or shipped name: what `sim`, `up` and world_sim all take."""
    return load(resolve(name_or_path))
