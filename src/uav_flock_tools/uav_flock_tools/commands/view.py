"""`uav-flock view`: a recorded run served to Foxglove or Lichtblick at its recorded pace."""
from __future__ import annotations

import argparse
from pathlib import Path

from .options import BAG_HELP, VIEW_PORT, UsageError, port, positive_float, serve_port

SUMMARY = 'play a recorded run into the live view (Foxglove WebSocket) at its pace'


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('bag', help=BAG_HELP)
    p.add_argument('--port', type=port, default=VIEW_PORT, help=f'WebSocket port (default {VIEW_PORT})')
    p.add_argument('--rate', type=positive_float, default=1.0, help='simulated seconds per wall second (default 1)')
    p.add_argument('--loop', action='store_true', help='start again at the end, until Ctrl-C')


def handle(args: argparse.Namespace) -> int:
    from .. import bag, view
    serve_port('view', '--port', args.port)
    try:
        path = bag.find_bag(Path(args.bag))
        sent = view.play(path, args.port, args.rate, args.loop)
    except (bag.BagError, ValueError) as exc:
        raise UsageError(f'view: {exc}') from None
    print(f'view: {sent} frames played')
    return 0

