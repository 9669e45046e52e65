"""`uav-flock run`, the README's first command, distributed: it flies the run over DDS with `up`'s options (their
defaults, whatever `up` gains) and writes the report of its bag."""
from __future__ import annotations

import argparse
from pathlib import Path

from helpers.runs import cli


def test_run_flies_distributed_records_and_reports(tmp_path: Path) -> None:
    done = cli('run', '--maps', '6', '--duration', '2', '--out', str(tmp_path / 'run'))
    assert done.returncode == 0, done.stdout + done.stderr
    assert 'Traceback' not in done.stderr
    for made in ('metrics.csv', 'trajectory.csv', 'bag/metadata.yaml', 'report/summary.md', 'report/flight.png',
                 'scenario.yaml', 'provenance.json'):
        assert (tmp_path / 'run' / made).exists(), made
    # The multirotor flew (run's default): the first line, the report's table and the run folder say so.
    assert 'multirotor vehicle' in done.stdout.splitlines()[0], done.stdout
    summary = (tmp_path / 'run' / 'report' / 'summary.md').read_text()
    assert '| multirotor |' in summary and 'least distance between two MAPs' in summary, summary


def test_run_hands_up_every_option_up_has() -> None:
    from uav_flock_tools.commands import run, up
    parser = argparse.ArgumentParser()
    up.add_arguments(parser)
    ns = run.up_options(argparse.Namespace(command='run', out='x'), record=True)
    assert set(vars(parser.parse_args([]))) <= set(vars(ns)) and ns.record is True
