"""`uav-flock replay`: one MAP's recorded inputs fed to a fresh agent node, its commands compared."""
from __future__ import annotations

import argparse
from dataclasses import fields
from pathlib import Path

from .options import BAG_HELP, UsageError, default_out, key_value, make_folder, non_negative_float, non_negative_int, positive_float

SUMMARY = "feed one MAP's recorded inputs to a fresh agent node, compare commands"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('bag', help=BAG_HELP)
    p.add_argument('--agent', type=non_negative_int, required=True, help='the MAP id to replay')
    p.add_argument('--tolerance', type=non_negative_float, default=1e-9,
                   help='largest |Δu| accepted (m/s^2, default 1e-9)')
    p.add_argument('--timeout', type=positive_float, default=20.0,
                   help='wait this long for each command (s, default 20)')
    p.add_argument('--set', type=key_value, action='append', metavar='KEY=VALUE',
                   help='an experiment: replay with an agent parameter changed, e.g. --set c1=0.4 (repeatable); '
                        f'exit 0 and a summary of how the commands differ. Keys: {", ".join(replay_keys())}')
    p.add_argument('--plot', metavar='PNG', help='with --set: where the plot of |Δu| over time goes '
                                                 '(default: replay_map<ID>.png in the run folder that holds '
                                                 'the bag, or in runs/replay-<time>/ for a bag of no run folder)')


def handle(args: argparse.Namespace) -> int:
    """Without --set a check (exit 1 if the agent now commands otherwise); with it an experiment (exit 0)."""
    from .. import bag, domains, replay
    if args.plot and not args.set:
        raise UsageError('replay: --plot draws the difference that --set makes: give --set KEY=VALUE')
    try:
        path = bag.find_bag(Path(args.bag))
        # Beside the bag in the run folder `up` made (run.json there); a bag elsewhere, perhaps tracked by git as
        # tests/golden/bag is, is not written beside: its picture goes into a new runs/replay-<time>/.
        home = path.parent if (path.parent / 'run.json').exists() else default_out('replay')
        plot = Path(args.plot) if args.plot else unused(home, f'replay_map{args.agent}')
        outcome = replay.replay(path, args.agent, args.tolerance, args.timeout, dict(args.set or []))
    except (bag.BagError, replay.ReplayError, domains.DomainInUse) as exc:
        raise UsageError(f'replay: {exc}') from None
    print(outcome.describe())
    if outcome.changed and outcome.du:
        import numpy as np

        from .. import plots
        make_folder(plot.parent, 'replay: --plot')  # only now: a refused --set leaves no empty folder behind
        t, du = np.array(outcome.du).T
        setting = ', '.join(f'{k}={v}' for k, v in outcome.changed.items())
        plots.command_difference(t, du, args.tolerance, f'MAP {args.agent} replayed with {setting}', plot)
        print(f'  |Δu| over time: {plot}')
    return 0 if outcome.ok else 1


def unused(folder: Path, stem: str) -> Path:
    """folder/stem.png, or stem-2.png, stem-3.png, ... if taken: a second experiment never overwrites the first."""
    path, n = folder / f'{stem}.png', 1
    while path.exists():
        n += 1
        path = folder / f'{stem}-{n}.png'
    return path


def replay_keys() -> list[str]:
    from uav_agent.core.params import FlockParams
    return [f.name for f in fields(FlockParams)]

