"""One lockstep run of N MAPs spread over 1, 2 and 3 hosts (network namespaces on this machine; needs root).

Run: ./uav-flock exec python benchmarks/bench_multihost.py [--maps 90 --duration 20 --hosts 1,2,3 --transports udp,tls]
The world host runs `up --listen` with its share of the MAPs, the others `agents --join` with theirs
(equal shares, the world's first); under tls each with `--secure` and keys made for the run (`uav-flock keys`:
every participant on TCP with TLS). Printed per transport and host count:
  start to first step   world_sim's wait until every MAP was matched (its "ready after" line)
  steps/s               simulated steps per wall second, once started (world_sim's last progress line)
  CPU per MAP-step      user + system CPU of every process in the hosts' namespaces from the first step
                        to the end / (MAPs x steps): start-up is not counted
  bytes per MAP-step    on the wire, from the first step on: bytes into the bridge from every host's veth
                        / (MAPs x steps);
                        with one host nothing crosses a wire, so its loopback's bytes are shown instead
All hosts share this machine's 2 cores, so more hosts add network work, not computing power.
"""
from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Optional

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'tests'))  # where tests and benchmarks keep helpers
from helpers import netns  # noqa: E402

SUBNET = '10.231.9'


def cli_in(ns: str, args: list[str], out: Path) -> subprocess.Popen[str]:
    return subprocess.Popen(netns.cli(ns, *args),
                            stdout=open(out, 'w'), stderr=subprocess.STDOUT, text=True)


def one(count: int, maps: int, duration: float, tmp: Path, tls: bool = False,
        per_process: Optional[int] = None) -> dict[str, float]:
    roles = [f'h{n}' for n in range(count)]
    shares = [maps * (n + 1) // count - maps * n // count for n in range(count)]
    tag = f'{"tls" if tls else "udp"}{count}'
    if tls:
        from uav_flock_tools import keys
        keys.make(tmp / f'{tag}-keys', roles)

    def extra(role: str) -> list[str]:  # --agents-per-process and, under tls, --secure
        packed = ['--agents-per-process', str(per_process)] if per_process else []
        return packed + (['--secure', str(tmp / f'{tag}-keys' / role)] if tls else [])

    with netns.hosts(roles, SUBNET) as names:
        world_out = tmp / f'{tag}-world.out'
        world = cli_in(names['h0'], ['up', '--maps', str(maps), '--duration', str(duration), '--listen', f'{SUBNET}.1',
                                     '--agents-here', str(shares[0]), '--out', str(tmp / f'{tag}-world'), *extra('h0')],
                       world_out)
        procs = [world]
        if count > 1:
            end = time.monotonic() + 120
            while not (m := re.search(r'--join (\S+)', world_out.read_text())) and time.monotonic() < end:
                time.sleep(0.2)
            if m is None:
                raise SystemExit(f'bench_multihost: the world printed no address to join:\n{world_out.read_text()}')
            first = shares[0]
            for n in range(1, count):
                ids = f'{first}-{first + shares[n] - 1}'
                procs.append(cli_in(names[f'h{n}'], ['agents', '--join', m.group(1), '--ids', ids,
                                                     '--out', str(tmp / f'{tag}-h{n}'), *extra(f'h{n}')],
                                    tmp / f'{tag}-h{n}.out'))
                first += shares[n]
        def wire() -> int:
            if count > 1:
                return sum(netns.counter(netns.bridge(), f'p{n}', 'rx_bytes') for n in range(1, count + 1))
            return netns.counter(names['h0'], 'lo', 'rx_bytes')

        cpu: dict[int, float] = {}
        at_start: tuple[float, int] | None = None  # CPU and bytes when the first step began: start-up is not counted
        while world.poll() is None:  # CPU time only grows: the last sample of each process is its total
            for ns in names.values():
                for pid in netns.pids(ns):
                    cpu[pid] = max(cpu.get(pid, 0.0), netns.cpu_seconds(pid))
            if at_start is None and 't =   0.0 s' in world_out.read_text():
                at_start = (sum(cpu.values()), wire())
            time.sleep(0.5)
        sent = wire()
        for p in procs[1:]:
            p.wait(timeout=60)
    if world.returncode != 0:
        raise SystemExit(f'bench_multihost: the run over {count} hosts failed:\n{world_out.read_text()}')
    log = (tmp / f'{tag}-world' / 'logs' / 'world.log').read_text() + world_out.read_text()
    ready = float(re.search(r'MAPs ready after ([\d.]+) s', log).group(1))  # type: ignore[union-attr]
    rate = float(re.findall(r'([\d.]+) steps/s', log)[-1])
    steps = round(duration / 0.1) + 1
    if at_start is None:
        raise SystemExit(f'bench_multihost: the run over {count} hosts never began a step')
    return {'start': ready, 'rate': rate, 'cpu': (sum(cpu.values()) - at_start[0]) / (maps * steps),
            'bytes': (sent - at_start[1]) / (maps * steps)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    ap.add_argument('--maps', type=int, default=90, help='MAPs (default: 90)')
    ap.add_argument('--duration', type=float, default=20.0, help='simulated s per run (default: 20)')
    ap.add_argument('--hosts', default='1,2,3', help='host counts to run (default: 1,2,3)')
    ap.add_argument('--agents-per-process', type=int, metavar='K',
                    help='K MAPs a process on every host, both transports (default: up\'s and agents\' own choice)')
    ap.add_argument('--transports', default='udp',
                    help='udp (plain DDS), tls (`--secure`: TCP with TLS), or both: udp,tls (default: udp)')
    args = ap.parse_args()
    try:
        counts = [int(h) for h in args.hosts.split(',')]
    except ValueError:
        ap.error(f'--hosts: expected counts like 1,2,3, got {args.hosts!r}')
    transports = [t.strip() for t in args.transports.split(',') if t.strip()]
    if args.maps < 1 or args.duration <= 0 or any(not 1 <= h <= 9 for h in counts):
        ap.error('--maps must be at least 1, --duration positive, host counts 1 to 9')
    if not transports or set(transports) - {'udp', 'tls'}:
        ap.error(f'--transports: udp, tls or udp,tls, got {args.transports!r}')
    rows = []
    with tempfile.TemporaryDirectory(prefix='uav-flock-multihost-') as tmp:
        for transport in transports:
            for count in counts:
                t0 = time.perf_counter()
                try:
                    r = one(count, args.maps, args.duration, Path(tmp), transport == 'tls', args.agents_per_process)
                except netns.NetnsError as exc:
                    print(f'bench_multihost: {exc}', file=sys.stderr)
                    return 2
                print(f'  {transport}, {count} host(s): {time.perf_counter() - t0:.0f} s', flush=True)
                rows.append((transport, count, r))
    packed = f'{args.agents_per_process} a process' if args.agents_per_process else 'packed as up and agents choose'
    print(f'\n{args.maps} MAPs ({packed}), lockstep, {args.duration:g} s simulated, hosts as network namespaces on one '
          'machine; udp: plain DDS, UDP only; tls: `--secure`, TCP with TLS only:\n')
    print('| transport | hosts | start to first step | steps/s | CPU per MAP-step | bytes per MAP-step |')
    print('|---|---|---|---|---|---|')
    for transport, count, r in rows:
        where = 'on the wire' if count > 1 else 'loopback, one host'
        print(f'| {transport} | {count} | {r["start"]:.1f} s | {r["rate"]:.1f} | {1e3 * r["cpu"]:.2f} ms | '
              f'{r["bytes"]:.0f} B ({where}) |')
    base = {count: r for transport, count, r in rows if transport == 'udp'}
    for transport, count, r in rows:
        if transport == 'tls' and count in base:
            print(f'tls against udp, {count} host(s): CPU per MAP-step x{r["cpu"] / base[count]["cpu"]:.2f}, '
                  f'bytes per MAP-step x{r["bytes"] / base[count]["bytes"]:.2f}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
