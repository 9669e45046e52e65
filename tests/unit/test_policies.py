"""The allocation registry (core/policies.py): a new allocation is a class and one line."""
from __future__ import annotations

import ast
import re
import types
from dataclasses import replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest

from uav_agent.core import policies
from uav_agent.core.clusters import ClusterMap
from uav_agent.core.links import Links
from uav_agent.core.params import FlockParams
from uav_agent.core.state import M0, M2, Memory, Near
from uav_flock_tools.batch import BatchSimulator
from world_sim.core.scenario import load


def docs_example() -> type:
    """The allocation of docs/design.md ("Adding an allocation"), executed from that page's own code block as the
    module it says to write (uav_agent/core/allocations/nearest.py): the docs cannot drift from what flies."""
    page = (Path(__file__).resolve().parents[2] / 'docs' / 'design.md').read_text()
    block = page.split('### Adding an allocation', 1)[1].split('```python\n', 1)[1].split('```', 1)[0]
    module = types.ModuleType('uav_agent.core.allocations.nearest')
    module.__package__ = 'uav_agent.core.allocations'
    exec(compile(block, 'docs/design.md', 'exec'), module.__dict__)
    return module.Nearest


Nearest = docs_example()


@pytest.mark.parametrize('channel', [Links(), Links(delivery='alpha', loss=0.3, burst=3.0, latency=2, ttl=6)],
                         ids=['paper', 'lossy-late'])
def test_a_new_allocation_is_a_class_and_one_registry_line(paper_scenario_path: str, monkeypatch: pytest.MonkeyPatch,
                                                            channel: Links) -> None:
    monkeypatch.setitem(policies.ALLOCATIONS, 'nearest', Nearest())
    s = load(paper_scenario_path).with_overrides(maps=30, duration=20.0)
    s = replace(s, flock=replace(s.flock, allocation='nearest'), links=channel)
    sim = BatchSimulator(s)
    result = sim.run()
    assert set(result.trajectory[:, 9].astype(int).tolist()) <= {M0, M2}, 'it never bridges'
    assert all(m.goal == sim.clusters.nearest(q, 0) for m, q in zip(sim.memory, sim.q)), \
        'every MAP ends serving its nearest cluster'


class Load(NamedTuple):
    steps: int = 0


class Own(NamedTuple):
    """docs/design.md's example of an allocation's own record: steps served, told to the neighbours."""

    served: int = 0
    heard: int = 0  # the largest count a neighbour told

    def said(self) -> Load:
        return Load(self.served)


class Counting(Nearest):
    def decide(self, mem: Memory, agent_id: int, n_users: int, r_g: float, q: np.ndarray, clusters: ClusterMap,
               fp: FlockParams, step: int, near: Near) -> Memory:
        own = mem.own or Own()
        told = [t.block.steps for t in near.told if t.block is not None]
        mem = super().decide(mem, agent_id, n_users, r_g, q, clusters, fp, step, near)
        return mem._replace(own=Own(own.served + 1, max([own.heard, *told])))


def test_an_allocation_keeps_its_own_record_and_hears_its_neighbours_blocks(paper_scenario_path: str,
                                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(policies.ALLOCATIONS, 'counting', Counting())
    s = load(paper_scenario_path).with_overrides(maps=20, duration=5.0)
    sim = BatchSimulator(replace(s, flock=replace(s.flock, allocation='counting')))
    sim.run()
    steps = s.steps + 1
    assert all(m.own.served == steps for m in sim.memory), 'every step kept in its own record'
    assert max(m.own.heard for m in sim.memory) == steps - 1, 'a neighbour\'s block of the step before'


def test_only_an_allocation_knows_its_own_names() -> None:
    """world_sim imports no allocation, and no module outside the demand allocation's own names its rules."""
    src = Path(__file__).resolve().parents[2] / 'src'
    for path in (src / 'world_sim').rglob('*.py'):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                names = [getattr(node, 'module', None) or ''] + [a.name for a in node.names]
                assert not any('allocations' in n for n in names), f'{path.name} imports an allocation'
    demand = src / 'uav_agent' / 'uav_agent' / 'core' / 'allocations' / 'demand'
    own = re.compile(r'\b(SLACK|STANDING|standing|kept|vacate|VACANT_STEPS)\(?\b')
    for path in src.rglob('*.py'):
        if demand in path.parents or 'build' in path.parts:
            continue
        code = [n.id for n in ast.walk(ast.parse(path.read_text())) if isinstance(n, ast.Name)]
        code += [n.attr for n in ast.walk(ast.parse(path.read_text())) if isinstance(n, ast.Attribute)]
        assert not [c for c in code if own.fullmatch(c)], f'{path.relative_to(src)} names a rule of the demand allocation'
