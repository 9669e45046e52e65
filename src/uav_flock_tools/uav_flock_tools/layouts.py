"""Random cluster layouts: `uav-flock layouts` writes them as scenario files, each with its MAP floor LB,
and the layout benchmark and `paper` run policy sets on them and tabulate how the runs ended."""
from __future__ import annotations

import math
import os
import signal
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Iterator, Optional

import numpy as np
import yaml

from uav_agent.core.params import FlockParams
from uav_agent.core.policies import POLICY_VALUES
from uav_flock_tools.batch import BatchSimulator
from world_sim.core import layouts, outcome
from world_sim.core.scenario import Scenario, ScenarioError, to_doc
from world_sim.shipped import load_scenario

INDEX = 'layouts.csv'


VEHICLE = 'multirotor'  # what random layouts fly unless told: the shipped profile (docs/vehicle.md)


def draw(scenario: str, count: int, clusters: tuple[int, int], seed: int, vehicle: str = VEHICLE) -> list[Scenario]:
    """count layouts on the scenario's other values, flown by that vehicle (`ideal`: the paper's, which the
    benchmarks of the paper's method keep); ScenarioError (one line) if they cannot be drawn."""
    base = load_scenario(scenario).with_overrides(vehicle=vehicle)
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
                  f'(docs/allocation.md); maps = ceil({factor:g} x LB).\n'
                  '# No `policies`: the default (demand) allocation runs.\n')
        (out / f'{name}.yaml').write_text(header + yaml.safe_dump(to_doc(s, policies=False), sort_keys=False))
        rows.append(f'{name}.yaml,{len(s.clusters)},{floor.total},{sum(floor.per_cluster)},'
                    f'{sum(floor.per_edge)},{s.maps}')
        print(f'{name}.yaml: {len(s.clusters)} clusters, LB = {floor.total}, maps = {s.maps}', flush=True)
    (out / INDEX).write_text('\n'.join(rows) + '\n')
    print(f'{len(drawn)} layouts in {out} (index: {out / INDEX}); run one with '
          f'./uav-flock sim --scenario {out}/layout-000.yaml')
    return 0


def policy_sets(paper: Scenario) -> dict[str, FlockParams]:
    """The flock of each policy set: 'default' is what a scenario without `policies` runs, 'paper' is
    paper.yaml's Algorithm 2, 'paper+share' the same with `edge_choice: share`."""
    defaults = {k: getattr(FlockParams(), k) for k in POLICY_VALUES}
    return {'default': replace(paper.flock, **defaults), 'paper': paper.flock,
            'paper+share': replace(paper.flock, edge_choice='share')}


@dataclass(frozen=True)
class Job:
    policy: str
    layout: int
    factor: float
    scenario: Scenario


@dataclass(frozen=True)
class Ended:
    job: Job
    floor: layouts.Floor
    outcome: outcome.Outcome


def jobs(paper: Scenario, drawn: list[Scenario], policies: list[str], factors: list[float], seeds: int,
         duration: float) -> list[Job]:
    """Every (policy set, layout, N = ceil(factor x LB), seed) run."""
    sets = policy_sets(paper)
    out = []
    for policy in policies:
        for n, lay in enumerate(drawn):
            lb = layouts.floor(lay).total
            for f in factors:
                for seed in range(seeds):
                    out.append(Job(policy, n, f, replace(lay, maps=math.ceil(f * lb), seed=seed, duration=duration,
                                                         flock=sets[policy])))
    return out


def run_job(job: Job) -> Ended:
    result = BatchSimulator(job.scenario).run()
    return Ended(job, layouts.floor(job.scenario), outcome.judge(job.scenario, result.metrics, result.trajectory))


def run_all(todo: list[Job], workers: Optional[int] = None) -> Iterator[Ended]:
    """Runs in parallel over the machine's cores, yielded as they end; Ctrl-C cancels the rest."""
    workers = workers or max(1, min(len(todo), os.cpu_count() or 1))
    with ProcessPoolExecutor(workers, initializer=signal.signal, initargs=(signal.SIGINT, signal.SIG_IGN)) as pool:
        futures = [pool.submit(run_job, j) for j in todo]
        try:
            for fut in as_completed(futures):
                yield fut.result()
        except BaseException:
            pool.shutdown(wait=True, cancel_futures=True)
            raise


def _pct(values: list[bool]) -> str:
    return f'{100 * np.mean(values):.0f} %' if values else '–'


def table(ended: list[Ended], policy: str, factors: list[float]) -> list[str]:
    """Markdown lines: success, time to success and where the MAPs ended, per N / LB; success by K."""
    mine = [e for e in ended if e.job.policy == policy]
    ks = sorted({len(e.job.scenario.clusters) for e in mine})
    lines = ['| N / LB | runs | success | ' + ' | '.join(f'K = {k}' for k in ks)
             + ' | median time to success (s) | R_c over last 10 s | connected | cluster MAPs / floor '
             '(median of min) | MAPs between discs / relay floor (median) | astray | M0 at end |',
             '|---' * (10 + len(ks)) + '|']
    for f in factors:
        rs = [e for e in mine if e.job.factor == f]
        if not rs:
            continue
        ok = [e.outcome.time_to_success for e in rs if e.outcome.success]
        cl = [min(n / max(d, 1) for n, d in zip(e.outcome.per_cluster, e.floor.per_cluster)) for e in rs]
        ed = [sum(e.outcome.per_edge) / max(sum(e.floor.per_edge), 1) for e in rs]
        by_k = [_pct([e.outcome.success for e in rs if len(e.job.scenario.clusters) == k]) for k in ks]
        lines.append(
            f'| {f:g} | {len(rs)} | **{_pct([e.outcome.success for e in rs])}** | ' + ' | '.join(by_k)
            + f' | {f"{np.median(ok):.1f}" if ok else "–"} | '
            f'{100 * np.mean([e.outcome.final_coverage for e in rs]):.1f} % | '
            f'{_pct([e.outcome.connected_tail for e in rs])} | {np.median(cl):.2f} | {np.median(ed):.2f} | '
            f'{np.mean([e.outcome.astray for e in rs]):.1f} | {np.mean([e.outcome.in_m0 for e in rs]):.1f} |')
    return lines


def evaluate(paper: Scenario, count: int, seeds: int, factors: list[float], policies: list[str],
             duration: float, layout_seed: int, progress: Callable[[int, int], None]) -> list[Ended]:
    """Draw count layouts and run every policy set on them; progress(done, total) after each run."""
    rng = np.random.default_rng(layout_seed)
    drawn = [layouts.draw(paper, layouts.LayoutSpec(), rng) for _ in range(count)]
    todo = jobs(paper, drawn, policies, factors, seeds, duration)
    ended: list[Ended] = []
    for e in run_all(todo):
        ended.append(e)
        progress(len(ended), len(todo))
    return ended
