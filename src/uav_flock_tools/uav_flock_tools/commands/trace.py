"""`uav-flock trace`: a run flown again, saying what split its network and why a MAP moved."""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Optional

from .options import UsageError, id_list, non_negative_float, own_process, positive_float

SUMMARY = ('fly a run again (a study\'s row, or a run folder): what split its network, and why a MAP moved; or a '
           'study\'s every split run (--outages)')
RUN_SCENARIO = 'scenario.yaml'  # what a run folder of `sim` or `up` keeps of the scenario it flew, to fly it again


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('source', metavar='SPEC|RUN_FOLDER',
                   help='a study spec (studies/*.yaml) or study folder (its spec.yaml; with --outages, the --out of '
                        '`study`), or the run folder of a `sim` or lockstep `up` (its scenario.yaml)')
    p.add_argument('run', nargs='?',
                   help='of a study: the run, its key (the `key` column) or LAYOUT/SEED/KIND, say 19/0/drift:2')
    p.add_argument('--variant', help='of a study: the variant, when the spec flies the run under several')
    p.add_argument('--map', type=id_list, default=[], metavar='IDS',
                   help='MAPs to follow, a line each every --every s: 36, or 3,36, or 30-39 (default: none)')
    p.add_argument('--from', dest='t0', type=non_negative_float, default=0.0, help='start at this time, s (default: 0)')
    p.add_argument('--to', dest='t1', type=non_negative_float,
                   help='stop at this time, s (default: the end of the run)')
    p.add_argument('--every', type=positive_float, default=1.0, help='a line per MAP every this many s (default: 1)')
    p.add_argument('--outages', action='store_true',
                   help='of a study folder (--out of `study`): fly again each run that split after first convergence, '
                        'and tell what began each outage and whether the formation had formed, in one table')
    p.add_argument('--kind', help='with --outages: only the runs of this kind, as the study names it (static, drift:2)')


def handle(args: argparse.Namespace) -> int:
    from uav_agent.core import ablation

    from ..batch import BatchSimulator
    from ..study import engine
    from ..study.spec import SpecError, load, runs
    from ..trace import Window, pick, summary, trace
    path = Path(args.source)
    if args.outages:
        return outages(args, path)
    if args.kind is not None:
        raise UsageError('trace: --kind goes with --outages')
    off: tuple[str, ...] = ()
    if path.is_dir() and (path / RUN_SCENARIO).exists() and not (path / 'spec.yaml').exists():
        if args.run is not None or args.variant is not None:
            raise UsageError(f'trace: {path} is a run folder: it names one run, so no RUN or --variant')
        from .. import simrun
        s = simrun.load_scenario(str(path / RUN_SCENARIO))
        said = f'trace: {path}: '
        study_run = None
    else:
        if path.is_dir():
            path = path / 'spec.yaml'
            if not path.exists():
                raise UsageError(f'trace: {args.source}: a folder with neither spec.yaml (a study) nor '
                                 f'{RUN_SCENARIO} (a run of sim or up)')
        if args.run is None:
            raise UsageError('trace: a study names many runs: say which (its key, or LAYOUT/SEED/KIND)')
        try:
            grid = runs(load(path))
        except SpecError as exc:
            raise UsageError(f'trace: {exc}') from None
        try:
            run = pick(grid, args.run, args.variant)
        except ValueError as exc:
            raise UsageError(f'trace: {exc}') from None
        s, off = run.scenario(), run.off
        said = f'trace: layout {run.layout}, seed {run.seed}, {run.kind}, variant {run.variant} (key {run.key}): '
        study_run = run
    if any(i >= s.maps for i in args.map):
        raise UsageError(f'trace: --map: the run flies MAPs 0-{s.maps - 1}')
    if args.t1 is not None and args.t1 < args.t0:
        raise UsageError('trace: --to comes before --from')
    own_process('trace', [s.vehicle.model])
    rules = f'; rules off: {", ".join(off)}' if off else ''
    print(f'{said}{s.maps} MAPs, {s.duration:g} s, vehicle {s.vehicle.model}, safety {s.flock.safety}{rules}',
          flush=True)
    window = Window(tuple(args.map), args.t0, s.duration if args.t1 is None else args.t1, args.every)
    with ablation.switched_off(off):
        flight = (engine.flight(study_run, s, watch=True) if study_run is not None
                  else BatchSimulator(s, watch=True).flight())
        traced = trace(flight, window, sys.stdout)
    print('\n'.join(summary(traced, window)), flush=True)
    return 0


def _num(v: object) -> float:
    """A study row's figure, NaN where the run has none (a run that never converged or formed)."""
    return float('nan') if v is None else float(v)  # type: ignore[arg-type]


def _formed(row: dict) -> Optional[float]:
    """When a study row's formation first came to rest (its `formed`), or None if it never did."""
    t = _num(row['formed'])
    return None if math.isnan(t) else t


def _asked(args: argparse.Namespace, folder: Path) -> tuple[list[dict], list]:
    """`--outages`: the study folder's finished rows that --kind and --variant ask for, and its spec's runs; a user
    mistake is one line."""
    from ..study import engine
    from ..study.spec import SpecError, load, runs
    if args.run is not None or args.map or args.t0 or args.t1 is not None:
        raise UsageError('trace: --outages flies every run of the study from its first convergence: no RUN, --map, '
                         '--from or --to')
    if not (folder.is_dir() and (folder / 'spec.yaml').exists()):
        raise UsageError(f'trace: --outages reads a study folder (the --out of `study`, with its spec.yaml and '
                         f'results): {args.source} is not one')
    rows = engine.finished(folder)
    if not rows:
        raise UsageError(f'trace: {args.source} holds no finished run yet')
    try:
        grid = runs(load(folder / 'spec.yaml'))
    except SpecError as exc:
        raise UsageError(f'trace: {exc}') from None
    kinds, variants = sorted({r['kind'] for r in rows}), sorted({r['variant'] for r in rows})
    if args.kind is not None and args.kind not in kinds:
        raise UsageError(f'trace: --kind: no run of kind {args.kind!r} in {args.source} (it has {", ".join(kinds)})')
    if args.variant is not None and args.variant not in variants:
        raise UsageError(f'trace: --variant: no variant {args.variant!r} in {args.source} '
                         f'(it has {", ".join(variants)})')
    asked = [r for r in rows if (args.kind is None or r['kind'] == args.kind)
             and (args.variant is None or r['variant'] == args.variant)]
    return sorted(asked, key=lambda r: (r['variant'], r['kind'], r['layout'], r['seed'])), grid


def outages(args: argparse.Namespace, folder: Path) -> int:
    """`trace STUDY_FOLDER --outages`: each run of the study that split after first convergence flown again from
    it to its end (rows from its results, as `study` wrote them), a line each as it is done, then the census."""
    import os

    from uav_agent.core import ablation

    from ..study import engine
    from ..trace import Traced, Window, census, census_lines, pick, trace
    asked, grid = _asked(args, folder)
    chosen = [r for r in asked if r['error'] is None and not math.isnan(_num(r['converged']))]
    split = [(r, pick(grid, f'{r["layout"]}/{r["seed"]}/{r["kind"]}', r['variant']))
             for r in chosen if _num(r['connected']) < 1.0]
    own_process('trace', [run.scenario().vehicle.model for _, run in split[:1]])
    print(f'trace: {len(chosen)} of {len(asked)} runs converged, {len(split)} of them split after it: each flown again '
          f'from its first convergence', flush=True)
    never = Traced(0, [])
    seen = [(_num(r['converged']), _num(r['duration']), _formed(r), never)
            for r in chosen if _num(r['connected']) >= 1.0]
    done = 0
    try:
        for r, run in split:
            s = run.scenario()
            converged = _num(r['converged'])
            with ablation.switched_off(run.off), open(os.devnull, 'w') as quiet:  # the census is what it says
                traced = trace(engine.flight(run, s, watch=True), Window((), converged, s.duration), quiet)
            seen.append((converged, s.duration, _formed(r), traced))
            done += 1
            print(f'  {r["layout"]}/{r["seed"]}/{r["kind"]} {r["variant"]}: apart {traced.apart:.1f} s of the '
                  f'{s.duration - converged:.1f} s after first convergence, {len(traced.outages)} outage'
                  f'{"s" if len(traced.outages) != 1 else ""} ({done}/{len(split)})', flush=True)
    except KeyboardInterrupt:
        print(f'trace: interrupted after {done} of {len(split)} runs: the census of those and the runs that never '
              f'split', flush=True)
        print('\n'.join(census_lines(census(seen))), flush=True)
        return 130
    print('\n'.join(census_lines(census(seen))), flush=True)
    return 0
