"""What a run folder says of what ran, as Hydra keeps .hydra/config.yaml beside its outputs: the scenario as flown
(every override applied, the vehicle included), so that `sim --scenario <folder>/scenario.yaml` flies it again to
the bit, and where it came from (the command line, the uav-flock version, the git commit and a digest of the code
itself)."""
from __future__ import annotations

import functools
import hashlib
import importlib
import json
import platform
import shlex
import subprocess
import sys
from importlib import metadata
from pathlib import Path
from typing import Any, Optional, Sequence

import yaml

from world_sim.core.scenario import Scenario, to_doc

SCENARIO_FILE = 'scenario.yaml'
PROVENANCE_FILE = 'provenance.json'
# The packages whose source decides what a run flies: their digest names the code whatever the checkout says.
CODE_PACKAGES = ('uav_agent', 'world_sim', 'uav_flock_tools')
HEADER = ('# The scenario as this run flew it, every override applied. Flown again to the bit:\n'
          '#   ./uav-flock sim --scenario {path}\n')


def version() -> str:
    try:
        return metadata.version('uav_flock_tools')
    except metadata.PackageNotFoundError:  # a build tree without the package's metadata
        return 'unknown'


@functools.cache  # the checkout a process runs from does not change under it: one look for a sweep's folders
def commit() -> Optional[str]:
    """The checkout's git commit, '+dirty' when tracked files differ from it; None outside a git checkout. A dirty
    checkout's changes are named by code(), not here."""
    here = Path(__file__).resolve().parent
    try:
        head = subprocess.run(['git', '-C', str(here), 'rev-parse', 'HEAD'], capture_output=True, text=True,
                              timeout=10)
        if head.returncode != 0:
            return None
        dirty = subprocess.run(['git', '-C', str(here), 'status', '--porcelain', '--untracked-files=no'],
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.TimeoutExpired):
        return None
    return head.stdout.strip() + ('+dirty' if dirty else '')


@functools.cache  # the sources a process flies do not change under it
def code() -> str:
    """A digest (16 hex digits) of the sources of CODE_PACKAGES as this process imports them: two runs with the
    same digest flew the same code, also from a dirty checkout or a copy on PYTHONPATH, which the commit misses."""
    digest = hashlib.sha256()
    for name in CODE_PACKAGES:
        root = Path(importlib.import_module(name).__file__).parent
        for path in sorted(p for p in root.rglob('*') if p.is_file() and '__pycache__' not in p.parts):
            digest.update(f'{name}/{path.relative_to(root).as_posix()}\0'.encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def said(argv: Sequence[str]) -> dict[str, Any]:
    """Where a run or a study came from: its command line, and the code and libraries that flew it."""
    return {'command': ['uav-flock', *argv], 'command_line': shlex.join(['./uav-flock', *argv]),
            'uav_flock': version(), 'commit': commit(), 'code': code(), 'python': platform.python_version(),
            'numpy': metadata.version('numpy'), 'scipy': metadata.version('scipy')}


def record(folder: Path, s: Scenario, argv: Sequence[str], extra: Optional[dict[str, Any]] = None) -> None:
    """scenario.yaml and provenance.json into folder (made if need be)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / SCENARIO_FILE
    path.write_text(HEADER.format(path=path) + yaml.safe_dump(to_doc(s), sort_keys=False))
    run = {'scenario': SCENARIO_FILE, 'name': s.name, 'maps': s.maps, 'seed': s.seed, 'duration': s.duration,
           'vehicle': s.vehicle.model}
    (folder / PROVENANCE_FILE).write_text(json.dumps({**said(argv), **run, **(extra or {})}, indent=1) + '\n')


def argv_of(args: object) -> list[str]:
    """The command line a command was given (cli._main keeps it as args.argv), else this process's."""
    return list(getattr(args, 'argv', None) or sys.argv[1:])
