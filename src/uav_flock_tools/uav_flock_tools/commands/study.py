"""`uav-flock study`: a grid of runs (layouts x seeds x kinds x variants) as Dask tasks, into one Parquet
table; `--summary` says what it holds (docs/studies.md)."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .options import EXIT_INTERRUPTED, UsageError, own_process, positive_int

SUMMARY = 'many runs of a grid, on Dask (a local cluster or a scheduler\'s workers), into results.parquet'


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('spec', help='a study spec (YAML; studies/*.yaml, docs/studies.md), or with --summary a study folder')
    p.add_argument('--out', type=Path, help='the study folder: results.parquet, and the summary beside it')
    p.add_argument('--scheduler', metavar='tcp://HOST:PORT',
                   help='run on the workers of this Dask scheduler (default: a local cluster, one worker a core)')
    p.add_argument('--workers', type=positive_int, help='local cluster: worker processes (default: one a core)')
    p.add_argument('--summary', action='store_true', help='only summarise the study folder SPEC: summary.md, .csv, connected.png')
    p.add_argument('--keep', action='store_true',
                   help='also keep each run it computes as a time series: OUT/series/<key>.parquet (docs/studies.md)')


def _progress(done: int, total: int, elapsed: float) -> None:
    left = elapsed / done * (total - done) if done else 0.0
    eta = '' if not done or done == total else (f', about {left / 60:.0f} min left' if left >= 90
                                                  else f', about {max(left, 1):.0f} s left')
    print(f'  {done}/{total} runs, {elapsed:.0f} s{eta}', file=sys.stderr, flush=True)


def handle(args: argparse.Namespace) -> int:
    from ..study import engine, summary
    from ..study.spec import SpecError, load, runs
    if args.summary:
        folder = Path(args.spec)
        if not (folder / engine.RESULTS).exists():
            raise UsageError(f'study: {folder}: no {engine.RESULTS} (run the study first)')
        for path in summary.write(engine.finished(folder), folder):
            print(path)
        return 0
    if args.out is None:
        raise UsageError('study: give --out DIR, the study folder')
    try:
        spec = load(Path(args.spec))
    except SpecError as exc:  # names the path itself
        raise UsageError(f'study: {exc}') from None
    try:
        grid = runs(spec)
    except SpecError as exc:
        raise UsageError(f'study: {args.spec}: {exc}') from None
    if args.scheduler:
        _reach(args.scheduler)
    else:  # the airframes the variants fly, each set up in the local workers (airframes.environment)
        own_process('study', [next(r for r in grid if r.variant == v).scenario().vehicle.model for v in spec.variants])
    from .. import provenance
    try:
        engine.claim(args.out, Path(args.spec), {r.key for r in grid}, provenance.code())
    except engine.StudyError as exc:
        raise UsageError(f'study: {exc}') from None
    # the last command that flew into the folder; each row also names the code that flew it (`code`)
    said = provenance.said(provenance.argv_of(args))
    (args.out / provenance.PROVENANCE_FILE).write_text(json.dumps(said, indent=1) + '\n')
    print(f'study: {len(grid)} run{"s" if len(grid) != 1 else ""} into {args.out / engine.RESULTS}'
          f' on {args.scheduler or "a local cluster"}', file=sys.stderr, flush=True)
    try:
        done, total = engine.study(grid, args.out, args.scheduler, args.workers, _progress,
                                   lambda text: print(f'study: {text}', file=sys.stderr, flush=True), args.keep)
    except KeyboardInterrupt:
        keys = {r.key for r in grid}
        saved = sum(r['key'] in keys and r['error'] is None for r in engine.finished(args.out))
        print(f'uav-flock: study interrupted: {saved} of {len(grid)} runs kept in {args.out / engine.RESULTS} '
              f'(the same command computes the other {len(grid) - saved})', file=sys.stderr)
        return EXIT_INTERRUPTED
    except engine.StudyError as exc:
        print(f'uav-flock: error: study: {exc}', file=sys.stderr)
        return 1
    print(f'{args.out / engine.RESULTS}: {total} runs ({done} computed now)')
    keys = {r.key for r in grid}
    held = [r for r in engine.finished(args.out) if r['key'] in keys]
    failed = engine.raised(held) or engine.other_code(held, provenance.code())  # the latter: a scheduler's workers
    if failed:
        print(f'uav-flock: error: study: {failed}', file=sys.stderr)
        return 1
    return 0


def _reach(address: str) -> None:
    """A scheduler that is not there is one line and exit 2, not a Dask timeout's traceback."""
    import socket
    from urllib.parse import urlparse
    url = urlparse(address)
    if url.scheme != 'tcp' or not url.hostname or not url.port:
        raise UsageError(f'study: --scheduler {address!r}: expected tcp://HOST:PORT')
    try:
        socket.create_connection((url.hostname, url.port), timeout=5).close()
    except OSError as exc:
        raise UsageError(f'study: --scheduler {address}: no scheduler there ({exc.strerror or exc})') from None
