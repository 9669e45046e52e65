"""`uav-flock sim`: a scenario in-process, for one or more MAP counts and seeds (a sweep)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .options import (EXIT_INTERRUPTED, add_scenario_options, check_run_options, default_out, floor_note, own_process,
                      progress_bar, run_folder)

SUMMARY = 'run a scenario in-process for one or more MAP counts and seeds'


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_scenario_options(p, grid=True)
    p.add_argument('--pictures', action='store_true',
                   help="in a sweep, draw each run's own plots and formation.gif too (a single run always draws "
                        'them; a sweep otherwise draws only its coverage and Fiedler plots of all runs)')
    p.add_argument('--out', help='output folder (default: runs/sim-<time>)')
    p.add_argument('--replace', action='store_true', help='replace the earlier run in --out (refused otherwise)')


def handle(args: argparse.Namespace) -> int:
    from uav_agent.core.links import describe
    from world_sim.core import hearing, outcome, records

    from .. import plots, provenance, simrun
    cmd = args.command
    base = simrun.load_scenario(args.scenario).with_overrides(vehicle=args.vehicle)
    check_run_options(cmd, base, args)
    own_process(cmd, [base.vehicle.model])
    maps = args.maps or [base.maps]
    seeds = args.seed or [base.seed]
    out = run_folder(Path(args.out) if args.out else default_out(cmd), f'{cmd}: --out', args.replace)
    runs = simrun.grid(base, maps, seeds, duration=args.duration, fail_at=args.fail_at,
                       fail_fraction=args.fail_fraction)
    print(f'vehicle: {base.vehicle.describe()}', flush=True)  # first: the same layout flies apart on each
    if (note := floor_note(base, min(maps))) is not None:
        print(note, file=sys.stderr, flush=True)
    if not base.links.perfect:
        print(f'radio between MAPs: {describe(base.links)}', flush=True)
    several = len(runs) > 1
    total = sum(s.steps for s in runs)
    done: list[tuple[str, object]] = []
    with progress_bar(total=total, unit='step', desc='simulating') as bar:
        for s in runs:
            label = f'{s.maps} MAPs, seed {s.seed}'
            folder = out / f'maps{s.maps}_seed{s.seed}' if several else out
            bar.set_postfix_str(label)
            provenance.record(folder, s, provenance.argv_of(args))
            result, complete = simrun.simulate(s, bar.update)
            simrun.write_run(result, folder, label, pictures=not several or args.pictures)
            done.append((label, result))
            if not complete:
                bar.close()
                m = result.metrics
                print(f'uav-flock: interrupted at t = {m[-1, 1]:.1f} s; what was simulated is in {folder}',
                      file=sys.stderr)
                return EXIT_INTERRUPTED
    if several:
        series = [(label, r.metrics[:, 1], 100 * r.metrics[:, 2]) for label, r in done]
        plots.time_series(series, 'coverage ratio R_c (%)', f'Coverage, {base.name}', out / 'coverage.png')
        plots.fiedler_series([(label, r.metrics[:, 1], r.metrics[:, 3]) for label, r in done],
                             f'Connectivity, {base.name}', out / 'fiedler.png')
    for label, r in done:
        m = r.metrics
        print(f'{label}: t = {m[-1, 1]:.1f} s, R_c = {100 * m[-1, 2]:.1f} %, Fiedler = {m[-1, 3]:.4f}, '
              f'components = {int(m[-1, 5])}, alive = {int(m[-1, 4])}')
        if records.has_links(m):  # under a channel (world_sim/core/hearing.py)
            print(f'{" " * len(label)}  {hearing.summary(m)}')
        if not r.scenario.vehicle.ideal:
            print(f'{" " * len(label)}  {outcome.flight_summary(r.scenario, m, r.trajectory, r.users.centroids)}')
    if several:
        table = simrun.write_summary([r for _, r in done], out)
        print('\n'.join(['', 'Mean ± std over the seeds (time to success: first t with R_c ≥ 95 % and one network, λ2 > 0):',
                          *table, f'one row per run in {out / simrun.SUMMARY_FILE}']))
    print(f'results in {out}')
    return 0

