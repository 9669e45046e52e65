"""`uav-flock keys`: a run's CA and per-host certificates for TLS between hosts (docs/multihost.md)."""
from __future__ import annotations

import argparse
from pathlib import Path

from .options import UsageError

SUMMARY = "a run's certificate authority and a certificate per host, for TLS between hosts"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ..keys import DAYS
    p.add_argument('--out', required=True, help='a new folder for the keys: one folder per host in it')
    p.add_argument('--hosts', required=True, help='comma-separated host names, e.g. world,field1,field2')
    p.add_argument('--days', type=int, default=DAYS, help=f'how long the keys are valid (default: {DAYS})')
    p.add_argument('--replace', action='store_true', help='make new keys in a folder that holds keys already')


def handle(args: argparse.Namespace) -> int:
    from .. import keys
    try:
        hosts = keys.hosts_of(args.hosts)
        ca = keys.make(Path(args.out), hosts, args.replace, args.days)
    except keys.KeysError as exc:
        raise UsageError(f'keys: {exc}') from None
    print(f'keys: a run CA (SHA-256 {keys.fingerprint(ca)[:23]}...) and certificates for {", ".join(hosts)} in '
          f'{args.out}/<host>/, valid to {ca.not_valid_after_utc:%Y-%m-%d}; copy each folder to its host only')
    return 0
