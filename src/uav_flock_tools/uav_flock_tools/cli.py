"""uav-flock command line (behind ./uav-flock).

Running a scenario: `sim` (batch, in one process), `run` (the main job), `up` (distributed: world_sim and
the MAP agents as processes), `agents` (agents of another host joining an `up --listen`). Looking into a run:
`kill`, `echo`, `topics`, `report`, `replay`. Measuring a layout or the method: `floor`, `layouts`, `paper`.
"""
from __future__ import annotations

import argparse
import signal
import sys
import time
from dataclasses import fields
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any, Callable, NoReturn, Optional, Sequence

if TYPE_CHECKING:
    from world_sim.core.scenario import Scenario

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


class UsageError(Exception):
    """A user mistake: reported in one line, exit code 2."""


class _Parser(argparse.ArgumentParser):
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


RUN_MARKS = ('metrics.csv', 'run.json', 'bag')  # what every run folder of sim, up or run holds one of


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


def add_scenario_options(p: argparse.ArgumentParser, grid: bool, failures: bool = True) -> None:
    """grid: lists of MAP counts and seeds (a batch sweep); else one of each (a single distributed run)."""
    p.add_argument('--scenario', default='paper', help=SCENARIO_HELP)
    if grid:
        p.add_argument('--maps', type=count_list, help='MAP count(s), e.g. 90 or 40,60,80,100 (default: scenario)')
        p.add_argument('--seed', type=int_list, help='seed(s), e.g. 0 or 0,1,2 (default: scenario)')
    else:
        p.add_argument('--maps', type=positive_int, help='MAP count, e.g. 90 (default: scenario)')
        p.add_argument('--seed', type=non_negative_int, help='seed, e.g. 3 (default: scenario)')
    p.add_argument('--duration', type=positive_float, help='simulated time in s (default: scenario)')
    if failures:
        p.add_argument('--fail-at', type=positive_float,
                       help="time of the random failure in s (default: the scenario's failure.at; paper: none)")
        p.add_argument('--fail-fraction', type=fraction,
                       help="fraction of the MAPs failing at --fail-at, 0 to 1 (default: the scenario's "
                            'failure.fraction; paper: none)')


def check_failure(cmd: str, base: 'Scenario', args: argparse.Namespace) -> None:
    """A failure option that would do nothing is a mistake: say so rather than run without the failure."""
    duration = args.duration or base.duration
    if args.duration is not None and args.duration < base.dt:
        raise UsageError(f'{cmd}: --duration {args.duration:g} s is shorter than one step of the scenario '
                         f'(dt = {base.dt:g} s)')
    if args.fail_fraction and args.fail_at is None and base.fail_at is None:
        raise UsageError(f'{cmd}: --fail-fraction needs --fail-at (or failure.at in the scenario)')
    if args.fail_at is None:
        return
    if args.fail_fraction is None and not base.fail_fraction:
        raise UsageError(f'{cmd}: --fail-at needs --fail-fraction (or failure.fraction in the scenario)')
    if args.fail_at >= duration:
        raise UsageError(f'{cmd}: --fail-at {args.fail_at:g} s is not before the end of the run ({duration:g} s)')


def cmd_sim(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from . import plots, simrun
    cmd = args.command
    base = simrun.load_scenario(args.scenario)
    check_failure(cmd, base, args)
    maps = args.maps or [base.maps]
    seeds = args.seed or [base.seed]
    out = run_folder(Path(args.out) if args.out else default_out(cmd), f'{cmd}: --out', args.replace)
    runs = simrun.grid(base, maps, seeds, duration=args.duration, fail_at=args.fail_at,
                       fail_fraction=args.fail_fraction)
    if (note := floor_note(base, min(maps))) is not None:
        print(note, file=sys.stderr, flush=True)
    several = len(runs) > 1
    total = sum(s.steps for s in runs)
    done: list[tuple[str, object]] = []
    with tqdm(total=total, unit='step', desc='simulating', mininterval=0.5, dynamic_ncols=True) as bar:
        for s in runs:
            label = f'{s.maps} MAPs, seed {s.seed}'
            folder = out / f'maps{s.maps}_seed{s.seed}' if several else out
            bar.set_postfix_str(label)
            result, complete = simrun.simulate(s, bar.update)
            simrun.write_run(result, folder, label, pictures=not several or args.pictures)
            done.append((label, result))
            if not complete:
                bar.close()
                m = result.metrics
                print(f'uav-flock: interrupted at t = {m[-1, 1]:.1f} s; what was simulated is in {folder}',
                      file=sys.stderr)
                return EXIT_INTERRUPTED
    if several:
        series = [(label, r.metrics[:, 1], 100 * r.metrics[:, 2]) for label, r in done]
        plots.time_series(series, 'coverage ratio R_c (%)', f'Coverage, {base.name}', out / 'coverage.png')
        plots.fiedler_series([(label, r.metrics[:, 1], r.metrics[:, 3]) for label, r in done],
                             f'Connectivity, {base.name}', out / 'fiedler.png')
    for label, r in done:
        m = r.metrics
        print(f'{label}: t = {m[-1, 1]:.1f} s, R_c = {100 * m[-1, 2]:.1f} %, Fiedler = {m[-1, 3]:.4f}, '
              f'components = {int(m[-1, 5])}, alive = {int(m[-1, 4])}')
    if several:
        table = simrun.write_summary([r for _, r in done], out)
        print('\n'.join(['', 'Mean ± std over the seeds (time to success: first t with R_c ≥ 95 % and λ2 > 0):',
                          *table, f'one row per run in {out / simrun.SUMMARY_FILE}']))
    print(f'results in {out}')
    return 0


VIEW_PORT = 8765  # the live view's WebSocket port when --view names none (Foxglove's usual)
PROCESSES_PER_CORE = 4  # agent processes per core when packing is left to `up` (docs/benchmarks.md)


def auto_agents_per_process(maps: int, cores: Optional[int] = None) -> int:
    """About four agent processes per core, the MAPs shared among them: 12 a process for 90 MAPs on 2 cores.

    One process per MAP costs 2.1 times the CPU per MAP-step of ten per process (docs/benchmarks.md), and
    90 of them spend their first minute in discovery.
    """
    import math
    import os
    return max(1, math.ceil(maps / (PROCESSES_PER_CORE * (cores or os.cpu_count() or 1))))


def cmd_run(args: argparse.Namespace) -> int:
    """The main job: a scenario (the paper's with 90 MAPs by default), distributed and recorded, then its report."""
    ns = argparse.Namespace(command='run', scenario=args.scenario, maps=args.maps, seed=args.seed,
                            duration=args.duration, fail_at=None, fail_fraction=None,
                            out=args.out or str(default_out('run')), replace=args.replace)
    if args.batch:
        if args.view is not None:
            raise UsageError('run: --view watches the distributed run; --batch has no topics to watch')
        ns.__dict__.update(maps=None if args.maps is None else [args.maps],
                           seed=None if args.seed is None else [args.seed], pictures=None)
        return cmd_sim(ns)
    ns.__dict__.update(agents_per_process=None, domain_id=None, discovery='auto', record=True, sync='lockstep',
                       rate=1.0, listen=None, agents_here=None, view=args.view)
    code = cmd_up(ns)
    bag_path = Path(ns.out) / 'bag'
    if (bag_path / 'metadata.yaml').exists():
        code = cmd_report(argparse.Namespace(bag=str(bag_path), out=None, replace=True)) or code
    return code


def cmd_up(args: argparse.Namespace) -> int:
    """world_sim and the MAPs' agent processes (K MAPs a process), in lockstep or in real time."""
    from world_sim.shipped import resolve

    from . import domains, launcher, simrun
    cmd = args.command
    path = resolve(args.scenario)
    base = simrun.load_scenario(args.scenario)
    check_failure(cmd, base, args)
    s = base.with_overrides(maps=args.maps, seed=args.seed, duration=args.duration, fail_at=args.fail_at,
                            fail_fraction=args.fail_fraction)
    if args.rate != 1.0 and args.sync != 'realtime':
        raise UsageError(f'{cmd}: --rate sets the pace of --sync realtime; lockstep runs as fast as it can')
    if args.listen is not None:
        listen_address(args.listen)
    if args.agents_here is not None and args.listen is None:
        raise UsageError(f'{cmd}: --agents-here leaves MAPs to agents of other hosts: give --listen ADDRESS for them')
    if args.agents_here is not None and args.agents_here > s.maps:
        raise UsageError(f'{cmd}: --agents-here {args.agents_here}: the run has {s.maps} MAPs')
    if args.view is not None:
        serve_port(cmd, '--view', args.view)
    per_process = args.agents_per_process or auto_agents_per_process(s.maps)
    out = run_folder(Path(args.out) if args.out else default_out(cmd), f'{cmd}: --out', args.replace)
    try:
        code, result = launcher.up(path.resolve(), s, out.resolve(), per_process, args.domain_id,
                                   args.discovery, args.record, args.sync, args.rate, args.listen, args.agents_here,
                                   floor_note(s, s.maps), args.view)
    except (FileExistsError, ValueError, domains.DomainInUse) as exc:
        raise UsageError(f'{cmd}: {exc}') from None
    if result is None:
        return code or 1
    simrun.write_run(result, out, f'{s.maps} MAPs, seed {s.seed} (distributed)')
    m = result.metrics
    print(f'{s.maps} MAPs, seed {s.seed}: t = {m[-1, 1]:.1f} s, R_c = {100 * m[-1, 2]:.1f} %, '
          f'Fiedler = {m[-1, 3]:.4f}, alive = {int(m[-1, 4])}; results in {out}')
    if args.record:
        say_what_the_bag_lacks(out / 'bag')
    return code


def cmd_floor(args: argparse.Namespace) -> int:
    from world_sim.core import layouts

    from . import simrun
    s = simrun.load_scenario(args.scenario)
    floor = layouts.floor(s)
    print(f'{s.name}: LB = {floor.total} MAPs ({sum(floor.per_cluster)} to cover the clusters, '
          f'{sum(floor.per_edge)} to relay along the tree; the scenario flies {s.maps})')
    for k, n in enumerate(floor.per_cluster):
        print(f'  cluster {k}: {n}')
    for (a, b), n in zip(floor.edges, floor.per_edge):
        print(f'  edge {a}-{b}: {n}')
    return 0


def floor_note(s: 'Scenario', maps: int) -> Optional[str]:
    """One line when the MAPs asked for are below the floor LB of the scenario's layout (docs/allocation.md)."""
    from world_sim.core import layouts
    floor = layouts.floor(s).total
    if maps >= floor:
        return None
    return (f'note: {maps} MAPs is below the floor of this layout, LB = {floor} MAPs (coverage discs and relay '
            'chains no method can do without, docs/allocation.md): expect users uncovered or the network split')


def say_what_the_bag_lacks(path: Path) -> None:
    """One line if the bag misses commands the world used (only a writer that vanished first leaves one out)."""
    from . import bag
    try:
        missing = bag.missing_commands(bag.load(path))
    except bag.BagError:
        return  # the recorder's own end is reported by up
    if missing:
        print(f'up: the bag lacks {sum(map(len, missing.values()))} commands that world_sim used, at '
              f'{len(missing)} steps (their MAPs died before the recorder had them); `report` lists them',
              file=sys.stderr)


def listen_address(host: str) -> None:
    """An IPv4 address of this host (the discovery server binds it): one line if it is not."""
    import ipaddress
    import socket
    try:
        ipaddress.IPv4Address(host)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.bind((host, 0))
    except ValueError:
        raise UsageError(f'up: --listen: expected an IPv4 address of this host, got {host!r}') from None
    except OSError as exc:
        raise UsageError(f'up: --listen: {host} is not an address of this host ({exc.strerror})') from None


def cmd_agents(args: argparse.Namespace) -> int:
    """Agent processes on this host that join a run listening on another (`up --listen`)."""
    from . import join
    try:
        join.parse_address(args.join)
    except join.JoinError as exc:
        raise UsageError(f'agents: {exc}') from None
    out = run_folder(Path(args.out) if args.out else default_out('agents'), 'agents: --out', args.replace)
    try:
        return join.join(args.join, args.ids, out.resolve(),
                         args.agents_per_process or auto_agents_per_process(len(args.ids)), args.timeout)
    except join.JoinError as exc:
        if out.is_dir() and not any(out.iterdir()):
            out.rmdir()  # nothing joined: leave no empty folder behind
        raise UsageError(f'agents: {exc}') from None


def cmd_kill(args: argparse.Namespace) -> int:
    from .kill import kill
    if (args.ids is None) == (args.fraction is None):
        raise UsageError('kill: give exactly one of --ids or --fraction')
    try:
        killed, pids, whole = kill(Path(args.run), args.ids, args.fraction, args.whole_processes)
    except (FileNotFoundError, ValueError) as exc:
        raise UsageError(f'kill: {exc}') from None
    if whole:
        print(f'SIGKILLed MAPs {killed} (processes {pids})')
    else:
        print(f'killed MAPs {killed} (their nodes ended inside processes {pids}, whose other MAPs fly on; '
              'a MAP alone in its process was SIGKILLed with it)')
    return 0


def cmd_echo(args: argparse.Namespace) -> int:
    from . import echo
    try:
        return echo.echo(args.topic, args.once, args.timeout, args.run, args.domain_id)
    except (FileNotFoundError, echo.EchoError) as exc:
        raise UsageError(f'echo: {exc}') from None


def cmd_topics(args: argparse.Namespace) -> int:
    from . import echo
    try:
        return echo.topics(args.run, args.domain_id)
    except (FileNotFoundError, echo.EchoError) as exc:
        raise UsageError(f'topics: {exc}') from None


def cmd_report(args: argparse.Namespace) -> int:
    from . import bag, report
    try:
        path = bag.find_bag(Path(args.bag))
        out = Path(args.out) if args.out else (path.parent / 'report' if path.name == 'bag' else path / 'report')
        if out.is_dir() and any(out.iterdir()) and not args.replace:
            raise UsageError(f'report: {out} holds a report already; pass --replace to write it anew, '
                             'or --out for another folder')
        make_folder(out, 'report: --out')
        summary, files = report.report(path, out)
    except bag.BagError as exc:
        raise UsageError(f'report: {exc}') from None
    print(report.summary_table(summary))
    print(f'{len(files)} files in {out}')
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    from . import bag, view
    serve_port('view', '--port', args.port)
    try:
        path = bag.find_bag(Path(args.bag))
        sent = view.play(path, args.port, args.rate, args.loop)
    except (bag.BagError, ValueError) as exc:
        raise UsageError(f'view: {exc}') from None
    print(f'view: {sent} frames played')
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    """Without --set a check (exit 1 if the agent now commands otherwise); with it an experiment (exit 0)."""
    from . import bag, domains, replay
    if args.plot and not args.set:
        raise UsageError('replay: --plot draws the difference that --set makes: give --set KEY=VALUE')
    try:
        path = bag.find_bag(Path(args.bag))
        plot = Path(args.plot) if args.plot else path.parent / f'replay_map{args.agent}.png'  # beside the bag
        if args.set:
            make_folder(plot.parent, 'replay: --plot')
        outcome = replay.replay(path, args.agent, args.tolerance, args.timeout, dict(args.set or []))
    except (bag.BagError, replay.ReplayError, domains.DomainInUse) as exc:
        raise UsageError(f'replay: {exc}') from None
    print(outcome.describe())
    if outcome.changed and outcome.du:
        import numpy as np

        from . import plots
        t, du = np.array(outcome.du).T
        setting = ', '.join(f'{k}={v}' for k, v in outcome.changed.items())
        plots.command_difference(t, du, args.tolerance, f'MAP {args.agent} replayed with {setting}', plot)
        print(f'  |Δu| over time: {plot}')
    return 0 if outcome.ok else 1


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


def cmd_layouts(args: argparse.Namespace) -> int:
    from . import layouts
    out = Path(args.out) if args.out else default_out('layouts')
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise UsageError(f'layouts: --out {out} exists and is not an empty folder; name a new one')
    drawn = layouts.draw(args.scenario, args.count, args.clusters, args.seed)  # before any file: all or none
    return layouts.write(drawn, args.seed, args.factor, args.duration, make_folder(out, 'layouts: --out'))


DOCS = Path(__file__).resolve().parents[3] / 'docs'  # the repository's own docs/, beside src/ (paper --docs)


def cmd_paper(args: argparse.Namespace) -> int:
    """Into a run folder by default; into the tracked docs/results.md and docs/figures only with --docs."""
    from . import paper
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


RUN_INFO_TIMEOUT_S = 20.0  # agents --join: how long a run's /run_info is waited for


def command(sub: 'argparse._SubParsersAction[_Parser]', name: str, func: Callable[[argparse.Namespace], int],
            summary: str) -> _Parser:
    """A subcommand whose `--help` opens with the line `uav-flock --help` lists it with."""
    p = sub.add_parser(name, help=summary, description=summary[0].upper() + summary[1:] + '.')
    p.set_defaults(func=func)
    return p


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog='uav-flock', description=__doc__)
    sub = parser.add_subparsers(dest='command', required=True, parser_class=_Parser)
    add_run_commands(sub)
    add_inspect_commands(sub)
    add_study_commands(sub)
    return parser


AGENTS_PER_PROCESS_HELP = (f'K MAPs\' agent nodes in each process (default: about {PROCESSES_PER_CORE} processes per core, '
                           'ceil(MAPs / (4 x cores)): 12 for 90 MAPs on 2 cores; 1 gives each MAP a process of its '
                           'own, which costs twice the CPU and a slow start: 90 MAPs take several minutes)')


def add_run_commands(sub: 'argparse._SubParsersAction[_Parser]') -> None:
    """sim, run, up and agents: what runs a scenario."""
    from uav_flock_ros.qos import SYNC_MODES
    p = command(sub, 'sim', cmd_sim, 'run a scenario in-process for one or more MAP counts and seeds')
    add_scenario_options(p, grid=True)
    p.add_argument('--pictures', action='store_true',
                   help="in a sweep, draw each run's own plots and formation.gif too (a single run always draws "
                        'them; a sweep otherwise draws only its coverage and Fiedler plots of all runs)')
    p.add_argument('--out', help='output folder (default: runs/sim-<time>)')
    p.add_argument('--replace', action='store_true', help='replace the earlier run in --out (refused otherwise)')
    p = command(sub, 'run', cmd_run, 'the main job: a scenario (the paper with 90 MAPs) distributed and recorded, '
                                   'with plots and a report of its bag')
    add_scenario_options(p, grid=False, failures=False)
    p.add_argument('--batch', action='store_true', help='in one process with the batch simulator instead (seconds)')
    add_view_option(p)
    p.add_argument('--out', help='output folder (default: runs/run-<time>)')
    p.add_argument('--replace', action='store_true', help='replace the earlier run in --out (refused otherwise)')
    p = command(sub, 'up', cmd_up, 'run a scenario distributed: world_sim and the MAPs as agent processes')
    add_scenario_options(p, grid=False)
    p.add_argument('--agents-per-process', type=positive_int, metavar='K', help=AGENTS_PER_PROCESS_HELP)
    p.add_argument('--domain-id', type=domain_id,
                   help='ROS_DOMAIN_ID to use (default: one from 1 to 101 that no other run on this host holds)')
    p.add_argument('--discovery', choices=('auto', 'localhost', 'subnet', 'server'), default='auto',
                   help='LOCALHOST discovery, SUBNET (multicast) discovery, or a Fast DDS discovery server for '
                        'the run (auto: the server above 30 processes or 100 MAPs)')
    p.add_argument('--record', action='store_true', help='record every topic into RUN/bag (rosbag2, MCAP)')
    p.add_argument('--sync', choices=SYNC_MODES, default='lockstep',
                   help='lockstep: each step waits for every MAP (deterministic, equal to sim); realtime: steps '
                        'at a fixed pace on /clock, each MAP flying on the latest data it has')
    p.add_argument('--rate', type=positive_float, default=1.0,
                   help='realtime: simulated seconds per wall second (default: 1)')
    p.add_argument('--out', help='run folder (default: runs/up-<time>)')
    p.add_argument('--replace', action='store_true', help='replace the earlier run in --out (refused otherwise)')
    p.add_argument('--listen', metavar='ADDRESS', help='an IPv4 address of this host where agents of other hosts '
                   'join (the discovery server listens there; see `agents --join`)')
    add_view_option(p)
    p.add_argument('--agents-here', type=non_negative_int, metavar='N',
                   help='with --listen: run MAPs 0..N-1 here and wait for the others to join (default: all here)')
    p = command(sub, 'agents', cmd_agents, 'agent processes on this host that join a run of `up --listen` on another')
    p.add_argument('--join', required=True, metavar='HOST:PORT', help='the address `up --listen` printed')
    p.add_argument('--ids', type=id_list, required=True, help='MAP ids to run here, e.g. 30-89')
    p.add_argument('--agents-per-process', type=positive_int, metavar='K', help=AGENTS_PER_PROCESS_HELP)
    p.add_argument('--timeout', type=positive_float, default=RUN_INFO_TIMEOUT_S,
                   help=f'wait this long for the run to answer (s, default: {RUN_INFO_TIMEOUT_S:g})')
    p.add_argument('--out', help='folder for this host\'s logs and pids (default: runs/agents-<time>)')
    p.add_argument('--replace', action='store_true', help='replace an earlier folder in --out (refused otherwise)')


def add_view_option(p: argparse.ArgumentParser) -> None:
    p.add_argument('--view', nargs='?', const=VIEW_PORT, type=port, metavar='PORT',
                   help=f'serve the run live to Foxglove or Lichtblick on ws://localhost:PORT (default {VIEW_PORT})')


def add_inspect_commands(sub: 'argparse._SubParsersAction[_Parser]') -> None:
    """kill, echo, topics, report and replay: what looks into a run, or breaks it on purpose."""
    p = command(sub, 'kill', cmd_kill, 'kill MAPs of a running `up` as a crash would: a MAP packed with others has '
                                     'its node ended inside its process, the others fly on')
    p.add_argument('--run', required=True, help='the run folder of `up`')
    p.add_argument('--ids', type=int_list, help='MAP ids to kill, e.g. 3,7')
    p.add_argument('--fraction', type=fraction, help='fraction of the live MAPs to kill, chosen at random')
    p.add_argument('--whole-processes', action='store_true',
                   help='SIGKILL the whole agent processes of the MAPs named, with every MAP they hold')
    p = command(sub, 'echo', cmd_echo, 'print messages of a topic as `ros2 topic echo` does')
    p.add_argument('topic', help='the topic, e.g. /metrics or map_3/state (relative names are taken from /)')
    p.add_argument('--once', action='store_true', help='print one message and exit')
    p.add_argument('--timeout', type=positive_float, default=10.0,
                   help='wait at most this long for the first message, publisher or not (s, default 10)')
    p.add_argument('--run', help='a run folder of `up`: use its ROS_DOMAIN_ID')
    p.add_argument('--domain-id', type=domain_id, help='ROS_DOMAIN_ID to listen on (default: the environment)')
    p = command(sub, 'topics', cmd_topics, 'list topics with their types, as `ros2 topic list -t` does')
    p.add_argument('--run', help='a run folder of `up`: use its ROS_DOMAIN_ID')
    p.add_argument('--domain-id', type=domain_id, help='ROS_DOMAIN_ID to look at (default: the environment)')
    p = command(sub, 'report', cmd_report, "plots and a summary table from a run's bag (ours or ros2 bag record's)")
    p.add_argument('bag', help=BAG_HELP)
    p.add_argument('--out', help='output folder (default: RUN/report next to the bag)')
    p.add_argument('--replace', action='store_true', help='write over an earlier report in that folder (refused otherwise)')
    p = command(sub, 'view', cmd_view, 'play a recorded run into the live view (Foxglove WebSocket) at its pace')
    p.add_argument('bag', help=BAG_HELP)
    p.add_argument('--port', type=port, default=VIEW_PORT, help=f'WebSocket port (default {VIEW_PORT})')
    p.add_argument('--rate', type=positive_float, default=1.0, help='simulated seconds per wall second (default 1)')
    p.add_argument('--loop', action='store_true', help='start again at the end, until Ctrl-C')
    p = command(sub, 'replay', cmd_replay, "feed one MAP's recorded inputs to a fresh agent node, compare commands")
    p.add_argument('bag', help=BAG_HELP)
    p.add_argument('--agent', type=non_negative_int, required=True, help='the MAP id to replay')
    p.add_argument('--tolerance', type=non_negative_float, default=1e-9,
                   help='largest |Δu| accepted (m/s^2, default 1e-9)')
    p.add_argument('--timeout', type=positive_float, default=20.0,
                   help='wait this long for each command (s, default 20)')
    p.add_argument('--set', type=key_value, action='append', metavar='KEY=VALUE',
                   help='an experiment: replay with an agent parameter changed, e.g. --set c1=0.4 (repeatable); '
                        f'exit 0 and a summary of how the commands differ. Keys: {", ".join(replay_keys())}')
    p.add_argument('--plot', metavar='PNG', help='with --set: where the plot of |Δu| over time goes '
                                                 '(default: replay_map<ID>.png beside the bag folder)')


def replay_keys() -> list[str]:
    from uav_agent.core.params import FlockParams
    return [f.name for f in fields(FlockParams)]


def add_study_commands(sub: 'argparse._SubParsersAction[_Parser]') -> None:
    """floor, layouts and paper: what measures a layout, or the method over many runs."""
    p = command(sub, 'floor', cmd_floor, "the floor LB of a scenario's layout: the MAPs no method can do without")
    p.add_argument('--scenario', default='paper', help=SCENARIO_HELP)
    p = command(sub, 'layouts', cmd_layouts, 'draw random cluster layouts as scenario files, with the MAP floor of each')
    p.add_argument('--count', type=positive_int, default=10, help='layouts to draw (default: 10)')
    p.add_argument('--clusters', type=count_range, default=(3, 6), help='clusters per layout, N or LOW-HIGH '
                                                                          '(default: 3-6)')
    p.add_argument('--seed', type=non_negative_int, default=0, help='seed of the draws (default: 0)')
    p.add_argument('--factor', type=positive_float, default=1.5,
                   help='MAPs per layout as a multiple of its floor LB, rounded up (default: 1.5)')
    p.add_argument('--duration', type=positive_float, default=90.0, help='simulated time in s (default: 90)')
    p.add_argument('--scenario', default='paper', help='scenario the layouts take everything else from '
                                                       '(default: paper; its policies are left out)')
    p.add_argument('--out', help='a new folder for the scenario files (default: runs/layouts-<time>)')
    p = command(sub, 'paper', cmd_paper, "regenerate the paper's figures over several seeds and docs/results.md")
    p.add_argument('--scenario', default='paper', help=SCENARIO_HELP)
    p.add_argument('--seeds', type=positive_int, default=5, help='seeds per configuration (default: 5)')
    p.add_argument('--out', help='a new folder for results.md and figures/ (default: runs/paper-<time>)')
    p.add_argument('--replace', action='store_true', help='replace an earlier run in --out (refused otherwise)')
    p.add_argument('--docs', action='store_true',
                   help="write the repository's docs/results.md and docs/figures instead (what the docs show)")
    p.add_argument('--no-ablation', action='store_true', help="skip measuring the effect of each open choice")
    p.add_argument('--layouts', type=non_negative_int, default=20,
                   help='random layouts to compare the policy sets on (default: 20; 0 skips them)')


def _main(argv: Optional[Sequence[str]]) -> int:
    from world_sim.core.scenario import ScenarioError
    try:
        args, extra = build_parser().parse_known_args(argv)
        if extra:  # the top-level parser would say it without naming the subcommand
            raise UsageError(f'{args.command}: unrecognized arguments: {" ".join(extra)} '
                             f'(see `uav-flock {args.command} --help`)')
        args.argv = list(sys.argv[1:] if argv is None else argv)
        func: Callable[[argparse.Namespace], int] = args.func
        return func(args)
    except UsageError as exc:
        print(f'uav-flock: error: {exc}', file=sys.stderr)
        return EXIT_USAGE
    except ScenarioError as exc:  # the scenario, or an option that overrides a key of it
        print(f'uav-flock: error: {args.command}: {exc}', file=sys.stderr)
        return EXIT_USAGE


RETRY_INTERRUPT_S = 0.05


def _interrupt(signum: int, frame: Optional[FrameType]) -> None:
    raise KeyboardInterrupt


def _unraisable(args: 'sys.UnraisableHookArgs') -> None:
    """An interrupt that landed where Python swallows exceptions (a weakref callback of an import) is raised again.

    Otherwise a Ctrl-C or `kill PID` at that moment would be lost and the command would carry on.
    """
    if args.exc_type is KeyboardInterrupt:
        signal.setitimer(signal.ITIMER_REAL, RETRY_INTERRUPT_S)  # SIGALRM: _interrupt, once out of the callback
        return
    sys.__unraisablehook__(args)


def install_interrupts() -> None:
    """`kill PID` stops a command as Ctrl-C does, so its clean-up (children stopped, partial records) runs too."""
    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGALRM, _interrupt)
    sys.unraisablehook = _unraisable


def main(argv: Optional[Sequence[str]] = None) -> int:
    # Only the standard library is imported above: Ctrl-C while numpy, rclpy and the rest load is caught here too.
    install_interrupts()
    try:
        return _main(argv)
    except KeyboardInterrupt:
        print('uav-flock: interrupted', file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # The reader of our output left (`echo /metrics | head -3`): done, quietly, as `ros2 topic echo | head`.
        # What Python would still flush at exit goes nowhere instead of raising again.
        import os
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == '__main__':
    sys.exit(main())
