"""The uav-flock commands, one module each: its SUMMARY (the line `--help` lists it with), add_arguments(p)
and handle(args) -> exit code. A new command is a module here and a line in COMMANDS."""
from __future__ import annotations

from . import agents, echo, floor, keys, kill, layouts, paper, replay, report, run, sim, study, topics, trace, up, view

# In the order `uav-flock --help` lists them: running a scenario, looking into a run, measuring the method.
COMMANDS = (sim, run, up, agents, keys, kill, echo, topics, report, view, replay, trace, floor, layouts, paper, study)


def name(module: object) -> str:
    return module.__name__.rsplit('.', 1)[1]  # type: ignore[attr-defined]
