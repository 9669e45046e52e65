"""`uav-flock paper`: the paper's figures over several seeds, and results.md beside them."""
from __future__ import annotations

import argparse
from pathlib import Path

from .options import SCENARIO_HELP, UsageError, default_out, make_folder, non_negative_int, positive_int, run_folder

DOCS = Path(__file__).resolve().parents[4] / 'docs'  # the repository's own docs/, beside src/ (paper --docs)


SUMMARY = "regenerate the paper's figures over several seeds and docs/results.md"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('--scenario', default='paper', help=SCENARIO_HELP)
    p.add_argument('--seeds', type=positive_int, default=5, help='seeds per configuration (default: 5)')
    p.add_argument('--out', help='a new folder for results.md and figures/ (default: runs/paper-<time>)')
    p.add_argument('--replace', action='store_true', help='replace an earlier run in --out (refused otherwise)')
    p.add_argument('--docs', action='store_true',
                   help="write the repository's docs/results.md and docs/figures instead (what the docs show)")
    p.add_argument('--no-ablation', action='store_true', help="skip measuring the effect of each open choice")
    p.add_argument('--layouts', type=non_negative_int, default=20,
                   help='random layouts to compare the policy sets on (default: 20; 0 skips them)')


def handle(args: argparse.Namespace) -> int:
    """Into a run folder by default; into the tracked docs/results.md and docs/figures only with --docs."""
    from .. import paper
    from ..simrun import load_scenario
    if load_scenario(args.scenario).duration <= paper.FAIL_AT:  # the failure runs would see no failure
        raise UsageError(f'paper: --scenario {args.scenario}: its runs end before the failure runs\' failure at '
                         f'{paper.FAIL_AT:g} s; give a scenario with a longer duration')
    if args.docs and args.out:
        raise UsageError('paper: --docs writes docs/results.md and docs/figures; --out names another folder: give one')
    if args.docs:
        if not (DOCS / 'results.md').exists():
            raise UsageError(f'paper: --docs: no docs/results.md at {DOCS} (a copy of the repository is needed)')
        results, figures = DOCS / 'results.md', DOCS / 'figures'
    else:
        folder = run_folder(Path(args.out) if args.out else default_out('paper'), 'paper: --out', args.replace)
        results, figures = folder / 'results.md', folder / 'figures'
    make_folder(figures, 'paper: --out')
    import shlex
    ran = shlex.join(['./uav-flock', *args.argv])  # exactly what was typed, for results.md to name
    return paper.main(seeds=args.seeds, out=figures, docs=results, scenario=args.scenario,
                      ablation=not args.no_ablation, random_layouts=args.layouts, command=ran)

