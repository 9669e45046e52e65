"""`uav-flock echo`: the messages of a topic, as `ros2 topic echo` prints them."""
from __future__ import annotations

import argparse

from .options import UsageError, domain_id, positive_float

SUMMARY = 'print messages of a topic as `ros2 topic echo` does'


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('topic', help='the topic, e.g. /metrics or map_3/state (relative names are taken from /)')
    p.add_argument('--once', action='store_true', help='print one message and exit')
    p.add_argument('--timeout', type=positive_float, default=10.0,
                   help='wait at most this long for the first message, publisher or not (s, default 10)')
    p.add_argument('--run', help='a run folder of `up`: use its ROS_DOMAIN_ID')
    p.add_argument('--domain-id', type=domain_id, help='ROS_DOMAIN_ID to listen on (default: the environment)')


def handle(args: argparse.Namespace) -> int:
    from .. import echo
    try:
        return echo.echo(args.topic, args.once, args.timeout, args.run, args.domain_id)
    except (FileNotFoundError, echo.EchoError) as exc:
        raise UsageError(f'echo: {exc}') from None

