"""`uav-flock layouts`: random cluster layouts as scenario files, each with its MAP floor LB."""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

from world_sim.core import layouts
from world_sim.core.scenario import Scenario, ScenarioError, to_doc
from world_sim.scenarios import load_scenario

INDEX = 'layouts.csv'


def draw(scenario: str, count: int, clusters: tuple[int, int], seed: int) -> list[Scenario]:
    """count layouts on the scenario's other values; ScenarioError (one line) if they cannot be drawn."""
    base = load_scenario(scenario)
    spec = layouts.LayoutSpec(clusters=clusters)
    rng = np.random.default_rng(seed)
    try:
        return [layouts.draw(base, spec, rng) for _ in range(count)]
    except layouts.LayoutError as exc:
        raise ScenarioError(f'layouts: {exc}') from None


def write(drawn: list[Scenario], seed: int, factor: float, duration: float, out: Path) -> int:
    """A scenario file per layout in out, and an index of their floors."""
    rows = ['file,clusters,lb,lb_clusters,lb_edges,maps']
    for n, lay in enumerate(drawn):
        floor = layouts.floor(lay)
        name = f'layout-{n:03d}'
        s = replace(lay, name=name, maps=math.ceil(factor * floor.total), duration=duration)
        header = (f'# Random layout {n} of `uav-flock layouts --seed {seed}`: {len(s.clusters)} clusters.\n'
                  f'# Floor LB = {floor.total} MAPs: {list(floor.per_cluster)} per cluster, '
                  f'{list(floor.per_edge)} relays on MST edges {[list(e) for e in floor.edges]} '
                  f'(docs/layouts.md); maps = ceil({factor:g} x LB).\n'
                  '# No `policies`: the default (demand) allocation runs.\n')
        (out / f'{name}.yaml').write_text(header + yaml.safe_dump(to_doc(s, policies=False), sort_keys=False))
        rows.append(f'{name}.yaml,{len(s.clusters)},{floor.total},{sum(floor.per_cluster)},'
                    f'{sum(floor.per_edge)},{s.maps}')
        print(f'{name}.yaml: {len(s.clusters)} clusters, LB = {floor.total}, maps = {s.maps}', flush=True)
    (out / INDEX).write_text('\n'.join(rows) + '\n')
    print(f'{len(drawn)} layouts in {out} (index: {out / INDEX}); run one with '
          f'./uav-flock sim --scenario {out}/layout-000.yaml')
    return 0
