"""How soon N processes, one ROS node each, all find each other under each discovery setting.

Run: ./uav-flock exec python benchmarks/bench_discovery.py [N] [--modes localhost,server,subnet,profile]
                                                          [--timeout SECONDS]
(default: 91 processes, as many as a 90-MAP run with one process per MAP has ROS nodes; all four modes).
Each process makes one node and one publisher, then counts the nodes its graph lists every 0.25 s. For each
mode the benchmark prints how many processes saw all N nodes within the timeout, when the last and the
median of them did, and the CPU time of all processes. The modes are `up --discovery localhost|server|subnet`
exactly as `up` sets them, and 'profile': simple discovery configured by fastdds_localhost_udp.xml (next to
this script), which reaches beyond the 32 participants of rmw_fastrtps's LOCALHOST mode.
"""
from __future__ import annotations

import argparse
import multiprocessing
import os
import resource
import signal
import statistics
import sys
import time
from multiprocessing.synchronize import Event
from pathlib import Path
from typing import Optional

import rclpy  # imported once here, before the forks, as `up`'s agent template does: discovery is timed, not imports
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import Int64
from uav_flock_tools.cleanup import clean_shared_memory
from uav_flock_tools.domains import DiscoveryServer, claim_domain, discovery_server_address, ros_env

MODES = ('localhost', 'server', 'subnet', 'profile')
PROFILE = Path(__file__).resolve().parent / 'fastdds_localhost_udp.xml'
POLL_S = 0.25


def mode_env(mode: str, domain: int) -> dict[str, str]:
    if mode == 'server':
        return ros_env(domain, discovery_server_address(domain))
    if mode == 'profile':
        env = ros_env(domain, None, 'LOCALHOST')
        env.pop('FASTDDS_BUILTIN_TRANSPORTS')  # the profile names its own transport
        # Fast DDS 2.x reads the profile from this variable (FASTDDS_DEFAULT_PROFILES_FILE is 3.x).
        env.update(ROS_AUTOMATIC_DISCOVERY_RANGE='SYSTEM_DEFAULT', FASTRTPS_DEFAULT_PROFILES_FILE=str(PROFILE))
        return env
    return ros_env(domain, None, mode.upper())


def participant(index: int, n: int, env: dict[str, str], start: float, deadline: float,
                results: multiprocessing.Queue, everyone_done: Event) -> None:
    """One process: a node with a publisher, waiting until its graph lists all n nodes.

    It stays until every process has reported: one that left early would be missing from the late ones' graphs.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's: it ends every process
    os.environ.clear()
    os.environ.update(env)
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(f'probe_{index}')
    node.create_publisher(Int64, f'probe_{index}', 10)
    seen: Optional[float] = None
    while seen is None and time.monotonic() < deadline:
        if len(node.get_node_names()) >= n:
            seen = time.monotonic() - start
        else:
            time.sleep(POLL_S)
    results.put(seen)
    results.close()
    results.join_thread()
    everyone_done.wait(timeout=max(0.0, deadline - time.monotonic()) + 5.0)
    node.destroy_node()
    rclpy.shutdown()


def measure(mode: str, n: int, timeout: float) -> dict[str, float]:
    claim = claim_domain()  # no other run on this host shares the domain while we measure
    domain = claim.domain
    env = mode_env(mode, domain)
    server = None
    if mode == 'server':
        server = DiscoveryServer(discovery_server_address(domain), env, Path(os.devnull))
    ctx = multiprocessing.get_context('fork')  # this process has not initialised rclpy, so a plain fork is clean
    results: multiprocessing.Queue = ctx.Queue()
    everyone_done = ctx.Event()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.monotonic()
    deadline = start + timeout
    procs = [ctx.Process(target=participant, args=(i, n, env, start, deadline, results, everyone_done))
             for i in range(n)]
    try:
        for p in procs:
            p.start()
        seen = [results.get(timeout=timeout + 60) for _ in procs]
        everyone_done.set()
        until = time.monotonic() + 30
        for p in procs:
            p.join(timeout=max(0.1, until - time.monotonic()))
    finally:
        for p in procs:
            if p.is_alive():  # a participant that hangs in its teardown
                p.kill()
                p.join()
        if server is not None:
            server.stop()
        clean_shared_memory(env)
        claim.release()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    done = sorted(s for s in seen if s is not None)
    return {'all': len(done), 'last': done[-1] if len(done) == n else float('nan'),
            'median': statistics.median(done) if done else float('nan'),
            'cpu': after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime}


def main() -> int:
    parser = argparse.ArgumentParser(prog='bench_discovery', description=__doc__.split('\n')[0])
    parser.add_argument('n', nargs='?', type=int, default=91, help='processes (default: 91)')
    parser.add_argument('--modes', default=','.join(MODES), help=f'comma-separated, of {", ".join(MODES)}')
    parser.add_argument('--timeout', type=float, default=60.0, help='seconds each mode may take (default: 60)')
    args = parser.parse_args()
    modes = [m for m in args.modes.split(',') if m]
    unknown = [m for m in modes if m not in MODES]
    if unknown or not modes:
        parser.error(f'--modes: expected some of {", ".join(MODES)}, got {args.modes!r}')
    if args.n < 2 or args.timeout <= 0:
        parser.error('N must be at least 2 and --timeout positive')
    print(f'{"mode":10s} {"processes":>9s} {"saw all":>7s} {"last saw all s":>14s} {"median s":>8s} {"CPU s":>6s}',
          flush=True)
    try:
        for mode in modes:
            r = measure(mode, args.n, args.timeout)
            print(f'{mode:10s} {args.n:9d} {r["all"]:7d} {r["last"]:14.1f} {r["median"]:8.1f} {r["cpu"]:6.1f}',
                  flush=True)
    except KeyboardInterrupt:
        print('bench_discovery: interrupted', file=sys.stderr)
        return 130
    return 0


if __name__ == '__main__':
    sys.exit(main())
