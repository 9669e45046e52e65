"""`uav-flock topics`: a run's topics with their types, as `ros2 topic list -t` lists them."""
from __future__ import annotations

import argparse

from .options import UsageError, domain_id

SUMMARY = 'list topics with their types, as `ros2 topic list -t` does'


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('--run', help='a run folder of `up`: use its ROS_DOMAIN_ID')
    p.add_argument('--domain-id', type=domain_id, help='ROS_DOMAIN_ID to look at (default: the environment)')


def handle(args: argparse.Namespace) -> int:
    from .. import echo
    try:
        return echo.topics(args.run, args.domain_id)
    except (FileNotFoundError, echo.EchoError) as exc:
        raise UsageError(f'topics: {exc}') from None

