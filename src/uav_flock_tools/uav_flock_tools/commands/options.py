"""What every command shares: one-line user errors, option types, run folders and the scenario options.

An option's value is checked here as a scenario's or a node's is (uav_agent.core.checks): a mistake is one
line naming the option, exit code 2, before any work starts.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, NoReturn, Optional

if TYPE_CHECKING:
    from world_sim.core.scenario import Scenario

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


class UsageError(Exception):
    """A user mistake: reported in one line, exit code 2."""


class Parser(argparse.ArgumentParser):
    """One-line errors, and no prefix matching of options: `--map 40` is not taken for `--maps 40`."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        kwargs.setdefault('allow_abbrev', False)
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]

    def error(self, message: str) -> NoReturn:
        """`uav-flock: error: sim: ...`: the program named once, then the subcommand."""
        command = self.prog.removeprefix('uav-flock').strip()
        raise UsageError(f'{command + ": " if command else ""}{message} (see `uav-flock {command + " " if command else ""}--help`)')


def _ints_from(text: str, low: int, what: str) -> list[int]:
    parts = [v.strip() for v in text.split(',')]
    if '' in parts:  # `--maps 60,` or `--seed 0,,1`: a value left out, not one to drop silently
        raise argparse.ArgumentTypeError(f'expected {what} separated by commas, got {text!r} (an empty item)')
    try:
        values = [int(v) for v in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected integers separated by commas, got {text!r}') from None
    if not values or any(v < low for v in values):
        raise argparse.ArgumentTypeError(f'expected {what} separated by commas, got {text!r}')
    return values


def int_list(text: str) -> list[int]:
    return _ints_from(text, 0, 'non-negative integers')


def id_list(text: str) -> list[int]:
    """MAP ids as ranges and single ids: 30-89, or 0,1,2, or 0-9,20-29."""
    ids: list[int] = []
    for part in (p.strip() for p in text.split(',') if p.strip()):
        lo, sep, hi = part.partition('-')
        try:
            first, last = int(lo), int(hi if sep else lo)
        except ValueError:
            raise argparse.ArgumentTypeError(f'expected ids such as 30-89 or 0,1,2, got {text!r}') from None
        if first < 0 or last < first:
            raise argparse.ArgumentTypeError(f'expected non-negative ids, ranges low-high, got {part!r}')
        ids += range(first, last + 1)
    if not ids or len(set(ids)) != len(ids):
        raise argparse.ArgumentTypeError(f'expected distinct ids such as 30-89, got {text!r}')
    return sorted(ids)


def count_list(text: str) -> list[int]:
    return _ints_from(text, 1, 'positive integers')


def count_range(text: str) -> tuple[int, int]:
    """N or LOW-HIGH, positive integers."""
    low, sep, high = text.partition('-')
    try:
        lo, hi = int(low), int(high) if sep else int(low)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected N or LOW-HIGH, got {text!r}') from None
    if not 1 <= lo <= hi:
        raise argparse.ArgumentTypeError(f'expected 1 <= LOW <= HIGH, got {text!r}')
    return lo, hi


def key_value(text: str) -> tuple[str, object]:
    """KEY=VALUE, the value read as YAML (a number stays a number)."""
    import yaml
    key, sep, value = text.partition('=')
    if not sep or not key:
        raise argparse.ArgumentTypeError(f'expected KEY=VALUE, got {text!r}')
    try:
        return key, yaml.safe_load(value)
    except yaml.YAMLError:
        raise argparse.ArgumentTypeError(f'unreadable value in {text!r}') from None


def _number_in(text: str, integer: bool = False, **bounds: Any) -> Any:
    """An option's value checked as a scenario's or a node's is (uav_agent.core.checks), in argparse's words."""
    from uav_agent.core.checks import noun, number
    try:
        value: Any = int(text) if integer else float(text)
        return number(value, 'option', integer=integer, **bounds)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected {noun(integer=integer, **bounds)}, got {text!r}') from None


def positive_float(text: str) -> float:
    return _number_in(text, low=0.0, low_open=True)


def non_negative_float(text: str) -> float:
    return _number_in(text, low=0.0)


def positive_int(text: str) -> int:
    return _number_in(text, integer=True, low=1)


def non_negative_int(text: str) -> int:
    return _number_in(text, integer=True, low=0)


def fraction(text: str) -> float:
    return _number_in(text, low=0.0, high=1.0)


# Fast DDS derives its ports from the domain: above 232 they pass 65535 (the DDS spec's port mapping).
MAX_DOMAIN_ID = 232

def domain_id(text: str) -> int:
    return _number_in(text, integer=True, low=0, high=MAX_DOMAIN_ID)


MAX_PORT = 65535

def port(text: str) -> int:
    """A TCP port number, for every option that takes one (--view, view --port)."""
    return _number_in(text, integer=True, low=1, high=MAX_PORT)


def serve_port(cmd: str, option: str, number: int) -> None:
    """One line if the port cannot be served on now: the one check of every command that serves one."""
    import socket
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        try:
            probe.bind(('127.0.0.1', number))
        except OSError as exc:
            raise UsageError(f'{cmd}: {option} {number}: the port is in use ({exc.strerror}); '
                             f'give another ({option} PORT)') from None


LOG_INTERVAL_S = 5.0  # a progress bar's pace when it writes into a log or a pipe


class _Lines:
    """A progress bar's stream for a log or a pipe: each update a line of its own, not a `\r` over the last."""

    def __init__(self, stream: Any) -> None:
        self.stream = stream

    def write(self, text: str) -> None:
        text = text.replace('\r', '').rstrip('\n')
        if text.strip():
            self.stream.write(text + '\n')

    def flush(self) -> None:
        self.stream.flush()


def progress_bar(**options: Any) -> Any:
    """tqdm on stderr: redrawn in place on a terminal; elsewhere a line every LOG_INTERVAL_S."""
    from tqdm import tqdm
    if sys.stderr.isatty():
        return tqdm(mininterval=0.5, dynamic_ncols=True, **options)
    return tqdm(file=_Lines(sys.stderr), mininterval=LOG_INTERVAL_S, ncols=100, **options)


def default_out(kind: str) -> Path:
    return Path('runs') / f'{kind}-{time.strftime("%Y%m%d-%H%M%S")}'


def make_folder(path: Path, what: str) -> Path:
    """Create an output folder before any work, so that a bad --out is a one-line error, not a lost run."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise UsageError(f'{what}: {path} exists and is not a folder') from None
    except OSError as exc:
        raise UsageError(f'{what}: cannot create {path} ({exc.strerror})') from None
    return path


RUN_MARKS = ('metrics.csv', 'run.json', 'bag', 'scenario.yaml')  # what every run folder of sim, up or run holds one of

def run_folder(path: Path, what: str, replace: bool) -> Path:
    """A new folder for one run's files: an earlier run's folder is refused, or with replace removed whole first.

    Never two runs in one folder: their metrics, plots and bag would contradict each other.
    """
    if path.exists() and path.is_dir() and any(path.iterdir()):
        if not replace:
            raise UsageError(f'{what} {path} holds files already (an earlier run?); name a new folder, '
                             'or pass --replace to replace that run whole')
        looks_like_run = any((path / m).exists() for m in RUN_MARKS) or any(
            (sub / 'metrics.csv').exists() for sub in path.glob('maps*_seed*'))
        if not looks_like_run:
            raise UsageError(f'{what} {path} is not a run folder (no {", ".join(RUN_MARKS)}): '
                             'not removing it; name a new folder')
        import shutil
        shutil.rmtree(path)
    return make_folder(path, what)


SCENARIO_HELP = 'scenario YAML file, or a shipped name (default: paper)'

BAG_HELP = 'the bag folder: RUN/bag for `up --record`, or just RUN'


def add_scenario_options(p: argparse.ArgumentParser, grid: bool, failures: bool = True,
                         vehicle: str | None = None) -> None:
    """grid: lists of MAP counts and seeds (a batch sweep); else one of each (a single distributed run); vehicle:
    the default of --vehicle (None: the scenario's own)."""
    p.add_argument('--scenario', default='paper', help=SCENARIO_HELP)
    if grid:
        p.add_argument('--maps', type=count_list, help='MAP count(s), e.g. 90 or 40,60,80,100 (default: scenario)')
        p.add_argument('--seed', type=int_list, help='seed(s), e.g. 0 or 0,1,2 (default: scenario)')
    else:
        p.add_argument('--maps', type=positive_int, help='MAP count, e.g. 90 (default: scenario)')
        p.add_argument('--seed', type=non_negative_int, help='seed, e.g. 3 (default: scenario)')
    p.add_argument('--duration', type=positive_float, help='simulated time in s (default: scenario)')
    from world_sim.core.airframes import AIRFRAMES
    p.add_argument('--vehicle', choices=tuple(AIRFRAMES), default=vehicle,
                   help="what the MAPs fly: the paper's unbounded double integrator, or the shipped multirotor "
                        f"(docs/vehicle.md; default: {vehicle or 'the scenario' + chr(39) + 's own'})")
    if failures:
        p.add_argument('--fail-at', type=positive_float,
                       help="time of the random failure in s (default: the scenario's failure.at; paper: none)")
        p.add_argument('--fail-fraction', type=fraction,
                       help="fraction of the MAPs failing at --fail-at, 0 to 1 (default: the scenario's "
                            'failure.fraction; paper: none)')


def check_run_options(cmd: str, base: 'Scenario', args: argparse.Namespace) -> None:
    """A duration or failure option that would do other than asked is a mistake: say so rather than run, and a run
    this machine has not the memory for is refused before it is asked for."""
    duration = args.duration or base.duration
    if args.duration is not None and args.duration < base.dt:
        raise UsageError(f'{cmd}: --duration {args.duration:g} s is shorter than one step of the scenario '
                         f'(dt = {base.dt:g} s)')
    if args.duration is not None and abs(args.duration / base.dt - round(args.duration / base.dt)) > 1e-6:
        steps = args.duration / base.dt
        raise UsageError(f'{cmd}: --duration {args.duration:g} s is not a whole number of steps of '
                         f'{base.dt:g} s (give {int(steps) * base.dt:g} or {(int(steps) + 1) * base.dt:g})')
    maps = args.maps if isinstance(args.maps, int) else max(args.maps or [base.maps])
    check_memory(cmd, base, maps)
    from world_sim.core.records import ESTIMATE_COLUMNS, TRAJECTORY_COLUMNS
    steps, row = round(duration / base.dt) + 1, 8 * len(TRAJECTORY_COLUMNS + ESTIMATE_COLUMNS)  # float64 a column
    if steps * maps * row > (free := _free_memory()):
        raise UsageError(f'{cmd}: {duration:g} s is {steps:.3g} steps of {maps} MAPs: their trajectory alone would take '
                         f'{steps * maps * row / 2**30:.3g} GiB, and this machine has '
                         f'{free / 2**30:.0f} GiB free: a shorter --duration, or fewer MAPs')
    if args.fail_fraction and args.fail_at is None and base.fail_at is None:
        raise UsageError(f'{cmd}: --fail-fraction needs --fail-at (or failure.at in the scenario)')
    if args.fail_at is None:
        return
    if args.fail_fraction is None and not base.fail_fraction:
        raise UsageError(f'{cmd}: --fail-at needs --fail-fraction (or failure.fraction in the scenario)')
    if args.fail_at >= duration:
        raise UsageError(f'{cmd}: --fail-at {args.fail_at:g} s is not before the end of the run ({duration:g} s)')


def own_process(cmd: str, models: Iterable[str]) -> None:
    """Airframes that need their process set up before anything is imported (airframes.environment) fly in this
    command started again with it set, as the same process id (a study's local workers, its children, inherit
    it); one that needs a package not installed is a one-line mistake."""
    import os
    from world_sim.core import airframes
    need: dict[str, str] = {}
    for model in sorted(set(models)):
        if (why := airframes.missing(model)) is not None:
            raise UsageError(f'{cmd}: {why}')
        need.update(airframes.environment(model))
    if all(os.environ.get(k) == v for k, v in need.items()):
        return
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(sys.executable, [sys.executable, *sys.orig_argv[1:]], {**os.environ, **need})


def _free_memory() -> int:
    import psutil
    return int(psutil.virtual_memory().available)


def check_memory(cmd: str, s: 'Scenario', maps: int) -> None:
    """UsageError if the MAPs' radio pairs at release would take more memory than this machine has free."""
    from world_sim.core.physics import PAIR_BYTES, release_pairs
    pairs = release_pairs(maps, s.release_half_width, s.flock.r)
    need = pairs * PAIR_BYTES
    free = _free_memory()
    if need > free:
        raise UsageError(f'{cmd}: {maps} MAPs released in a square of {2 * s.release_half_width:g} m make about '
                         f'{pairs:.2g} pairs within r = {s.flock.r:g} m, about {need / 2**30:.0f} GiB to hold, and this '
                         f'machine has {free / 2**30:.0f} GiB free: fewer MAPs or a wider release.half_width')


def floor_note(s: 'Scenario', maps: int) -> Optional[str]:
    """A line when the MAPs asked for are below the floor LB of the scenario's layout (docs/allocation.md), and one
    when its clusters move but the MAPs are never told (users.survey: given)."""
    from world_sim.core import layouts
    floor = layouts.floor(s).total
    notes = []
    if maps < floor:
        notes.append(f'note: {maps} MAPs is below the floor of this layout, LB = {floor} MAPs (coverage discs and '
                     'relay chains no method can do without, docs/allocation.md): expect users uncovered or the '
                     'network split')
    if s.survey == 'given' and any(c.moves for c in s.clusters):
        notes.append("note: clusters of this scenario move, but the MAPs know them only as drawn (users.survey: "
                     "given): they stay where the users were; `survey: online` follows them (docs/scenarios.md)")
    return '\n'.join(notes) or None


VIEW_PORT = 8765  # the live view's WebSocket port when --view names none (Foxglove's usual)

def add_view_option(p: argparse.ArgumentParser) -> None:
    p.add_argument('--view', nargs='?', const=VIEW_PORT, type=port, metavar='PORT',
                   help=f'serve the run live to Foxglove or Lichtblick on ws://localhost:PORT (default {VIEW_PORT})')


PROCESSES_PER_CORE = 4  # agent processes per core when packing is left to `up` (docs/benchmarks.md)

# Under --secure (TCP with TLS), no more MAPs than this in one process: 90 MAPs at 12 a process stalled at step 0 in 7
# of 7 starts on one host, their agents never told of their neighbours' writers; at 4 a process they ran
# (docs/multihost.md).
SECURE_AGENTS_PER_PROCESS = 4


def auto_agents_per_process(maps: int, cores: Optional[int] = None, secure: bool = False) -> int:
    """About four agent processes per core, the MAPs shared among them: 12 a process for 90 MAPs on 2 cores;
    under --secure at most SECURE_AGENTS_PER_PROCESS.

    One process per MAP costs 2.1 times the CPU per MAP-step of ten per process (docs/benchmarks.md), and
    90 of them spend their first minute in discovery.
    """
    import math
    import os
    k = max(1, math.ceil(maps / (PROCESSES_PER_CORE * (cores or os.cpu_count() or 1))))
    return min(k, SECURE_AGENTS_PER_PROCESS) if secure else k


AGENTS_PER_PROCESS_HELP = (f'K MAPs\' agent nodes in each process (default: about {PROCESSES_PER_CORE} processes per core, '
                           'ceil(MAPs / (4 x cores)): 12 for 90 MAPs on 2 cores; 1 gives each MAP a process of its '
                           'own, which costs twice the CPU and a slow start: 90 MAPs take several minutes)')


def host_keys(cmd: str, folder: Optional[Path]):  # -> Optional[keys.HostKeys]
    """--secure's folder, checked before anything starts: a missing or unreadable file, a certificate the CA did
    not sign, one out of date or for another host than the folder is named for, is one line and exit 2."""
    if folder is None:
        return None
    from .. import keys
    try:
        return keys.check(folder, folder.resolve().name)
    except keys.KeysError as exc:
        raise UsageError(f'{cmd}: {exc}') from None
