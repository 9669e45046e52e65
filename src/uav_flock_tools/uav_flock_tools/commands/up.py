"""`uav-flock up`: world_sim and the MAPs' agent processes over DDS, in lockstep or in real time."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .options import (AGENTS_PER_PROCESS_HELP, UsageError, add_scenario_options, add_view_option,
                      auto_agents_per_process, check_run_options, default_out, domain_id, floor_note, host_keys, non_negative_int,
                      positive_float, positive_int, run_folder, serve_port)

SUMMARY = 'run a scenario distributed: world_sim and the MAPs as agent processes'


def add_arguments(p: argparse.ArgumentParser) -> None:
    from uav_flock_ros.qos import SYNC_MODES
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
    p.add_argument('--secure', type=Path, metavar='KEYS/HOST',
                   help='with --listen: this host\'s folder of `uav-flock keys`; every participant of the run on TCP '
                        'with TLS, peers verified against the run\'s CA (docs/multihost.md)')
    add_view_option(p)
    p.add_argument('--start-timeout', type=positive_float, metavar='SECONDS',
                   help='how long world_sim waits for every MAP to appear, and each MAP for world_sim (default: '
                        '60 s, or 1.5 s a process when more; 300 s with --listen)')
    p.add_argument('--agents-here', type=non_negative_int, metavar='N',
                   help='with --listen: run MAPs 0..N-1 here and wait for the others to join (default: all here)')


def handle(args: argparse.Namespace) -> int:
    """world_sim and the MAPs' agent processes (K MAPs a process), in lockstep or in real time."""
    from world_sim.shipped import resolve

    from world_sim.core import airframes

    from .. import domains, launcher, provenance, simrun
    cmd = args.command
    path = resolve(args.scenario)
    base = simrun.load_scenario(args.scenario)
    check_run_options(cmd, base, args)
    s = base.with_overrides(maps=args.maps, seed=args.seed, duration=args.duration, fail_at=args.fail_at,
                            fail_fraction=args.fail_fraction, vehicle=args.vehicle)
    if (why := airframes.missing(s.vehicle.model)) is not None:
        raise UsageError(f'{cmd}: {why}')
    if args.rate != 1.0 and args.sync != 'realtime':
        raise UsageError(f'{cmd}: --rate sets the pace of --sync realtime; lockstep runs as fast as it can')
    if args.listen is not None:
        listen_address(args.listen)
    keys = host_keys(cmd, args.secure)
    if keys is not None and args.listen is None:
        raise UsageError(f'{cmd}: --secure keeps strangers out of a run over several hosts: give --listen ADDRESS too')
    if args.agents_here is not None and args.listen is None:
        raise UsageError(f'{cmd}: --agents-here leaves MAPs to agents of other hosts: give --listen ADDRESS for them')
    if args.agents_here is not None and args.agents_here > s.maps:
        raise UsageError(f'{cmd}: --agents-here {args.agents_here}: the run has {s.maps} MAPs')
    if args.view is not None:
        serve_port(cmd, '--view', args.view)
    per_process = args.agents_per_process or auto_agents_per_process(s.maps, secure=keys is not None)
    out = run_folder(Path(args.out) if args.out else default_out(cmd), f'{cmd}: --out', args.replace)
    provenance.record(out, s, provenance.argv_of(args))
    try:
        code = launcher.up(path.resolve(), s, out.resolve(), per_process, args.domain_id, args.discovery, args.record,
                           args.sync, args.rate, args.listen, args.agents_here, floor_note(s, s.maps), args.view,
                           keys, args.start_timeout)
    except (FileExistsError, ValueError, domains.DomainInUse) as exc:
        raise UsageError(f'{cmd}: {exc}') from None
    result = simrun.read_run(out, s)
    if result is None:
        return code or 1
    simrun.write_run(result, out, f'{s.maps} MAPs, seed {s.seed} (distributed)')
    m = result.metrics
    from world_sim.core import outcome, records
    if records.has_links(m):  # under a channel (world_sim/core/hearing.py): what the MAPs heard, as sim says it
        from world_sim.core import hearing
        print(f'uav-flock up: radio: {hearing.summary(m)}')
    if not s.vehicle.ideal:
        print(f'uav-flock up: flight: {outcome.flight_summary(s, m, result.trajectory, result.users.centroids)}')
    print(f'{s.maps} MAPs, seed {s.seed}: t = {m[-1, 1]:.1f} s, R_c = {100 * m[-1, 2]:.1f} %, '
          f'Fiedler = {m[-1, 3]:.4f}, alive = {int(m[-1, 4])}; results in {out}')
    if args.record:
        say_what_the_bag_lacks(out / 'bag')
    return code


def say_what_the_bag_lacks(path: Path) -> None:
    """One line if the bag misses commands the world used (only a writer that vanished first leaves one out)."""
    from .. import bag
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

