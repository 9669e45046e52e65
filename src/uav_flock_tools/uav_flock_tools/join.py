"""`agents --join`: agent processes on this host that join a run whose world listens on another.

The world's host runs `up --listen ADDRESS --agents-here N`: its discovery server listens on ADDRESS and
world_sim publishes /run_info (latched), which says how many MAPs the run has, which of them join from other
hosts and the agents' parameters. A joining host needs nothing from the world's files: it fetches /run_info
through the discovery server, checks the ids it was asked for, and forks its agents as `up` does. Its
folder holds its own logs, parameters and pids.json, so `kill --run FOLDER` works on it as on a run of `up`.
"""
from __future__ import annotations

import json
import multiprocessing
import os
import signal
import time
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Optional

from uav_flock_ros.processes import CRASH_DIR, LINKS_LOG_DIR, TEARDOWN_SIGNAL, write_params

from . import secure
from .domains import DISCOVERY_BASE_PORT, adopt, ros_env
from .keys import HostKeys
from .spawn import ForkedAgent, start_agents, stop, write_pid_table

POLL_S = 0.5
# A joining host's agents make their DDS participant anew if they have not seen world_sim this long (s; the
# agent's renew_unseen, 60 s where agents may start before the world): here the world is up, its run fetched
# from it, so a participant still blind after 20 s was cut off from discovery (a refused TLS handshake under load
# held a secured run's start 60 s in the whole suite, 11 of 12 MAPs ready).
JOINED_RENEW_S = 20.0
FETCH_TRY_S = JOINED_RENEW_S  # one participant's try at /run_info; a blind one is renewed after this long
FETCH_GRACE_S = 10.0  # beyond its try, for a child's rclpy.init and participant (a loaded two-core host)


class JoinError(Exception):
    """A join that cannot go ahead: no run at that address, or ids it does not have. One line, exit 2."""


def parse_address(text: str) -> tuple[str, int]:
    """HOST:PORT of a run's discovery server, and the ROS_DOMAIN_ID its port stands for."""
    host, sep, port = text.rpartition(':')
    if not sep or not host or not port.isdigit():
        raise JoinError(f'--join: expected HOST:PORT as `up --listen` prints it, got {text!r}')
    domain = int(port) - DISCOVERY_BASE_PORT
    if not 0 <= domain <= 232:
        raise JoinError(f'--join: port {port} is no run\'s (`up` listens on {DISCOVERY_BASE_PORT} + its domain id)')
    return host, domain


def listen_for_run_info(timeout: float) -> str:
    """The text of the first /run_info heard within timeout through the run's discovery server (this process's
    environment is the run's: fetch_run_info adopted it before the fork), or ''."""
    import rclpy
    import rclpy.executors
    from rclpy.signals import SignalHandlerOptions
    from std_msgs.msg import String

    from uav_flock_ros.qos import LATCHED_QOS
    got: list[str] = []
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('uav_flock_join')
    executor = rclpy.executors.SingleThreadedExecutor()
    executor.add_node(node)
    node.create_subscription(String, '/run_info', lambda m: got.append(m.data), LATCHED_QOS)
    end = time.monotonic() + timeout
    while not got and time.monotonic() < end:
        executor.spin_once(timeout_sec=POLL_S)
    return got[0] if got else ''


def fetch_once(timeout: float, answer: Connection) -> None:
    """Body of one fetch's child process: sends what it heard and leaves by os._exit, past the DDS teardown (a
    TLS participant's has held a process for minutes)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)  # Ctrl-C ends the child at once; the parent says so
    try:
        answer.send(listen_for_run_info(timeout))
    finally:
        os._exit(0)


def fetch_run_info(address: str, env: dict[str, str], timeout: float, tls: bool = False) -> dict[str, object]:
    """The run's /run_info, read through its discovery server (env: the run's); JoinError if nothing answers
    in time.

    Each try is a child process with a participant of its own, killed once it has answered or its time is up:
    in a whole suite one joining host's fetch over TLS printed nothing for 300 s (a participant blind to a
    handshake refused under load, or one whose teardown hung), and its run waited for its MAPs to the end.
    """
    adopt(env)
    forks = multiprocessing.get_context('fork')  # nothing of DDS lives in this process to be copied
    end = time.monotonic() + timeout
    while (left := end - time.monotonic()) > 0:
        window = min(left, FETCH_TRY_S)
        heard, answer = forks.Pipe(duplex=False)
        child = forks.Process(target=fetch_once, args=(window, answer), daemon=True)
        child.start()
        answer.close()
        try:
            text = heard.recv() if heard.poll(window + FETCH_GRACE_S) else ''
        except EOFError:  # the child ended without a word (its log is this terminal)
            text = ''
        finally:
            child.kill()
            child.join()
            heard.close()
        if text:
            return json.loads(text)
    port = address.rpartition(':')[2]
    if tls:
        raise JoinError(f'no run answers at {address}: nothing on /run_info within {timeout:g} s (is `up --listen '
                        f'--secure` running there with keys of the same `uav-flock keys`, and TCP port {port} '
                        f'open to this host?)')
    raise JoinError(f'no run answers at {address}: nothing on /run_info within {timeout:g} s (is `up --listen` '
                    f'running there, and UDP port {port} open to this host?)')


def check_ids(ids: list[int], info: dict[str, object]) -> None:
    first, last = info['remote_ids']  # type: ignore[misc]
    outside = [i for i in ids if not first <= i <= last]
    if outside:
        raise JoinError(f'--ids: MAP {outside[0]} is not one this run waits for from other hosts (it has '
                        f'{info["maps"]} MAPs; {first}-{last} join from other hosts)')


def join(address: str, ids: list[int], out: Path, agents_per_process: int, timeout: float,
         keys: Optional[HostKeys] = None) -> int:
    """Fetch the run, start its agents `ids` here, and wait until they end (with the run, or on Ctrl-C).
    With keys, over TCP with TLS as the run's `up --secure` (secure.py)."""
    _, domain = parse_address(address)
    secured = secure.for_run(keys, address, out) if keys is not None else None
    env = secure.role_env(ros_env(domain, address), out, keys, 'client')
    info = fetch_run_info(address, env, timeout, keys is not None)
    check_ids(ids, info)
    out.mkdir(parents=True, exist_ok=True)
    here = {'crash_dir': str(out / CRASH_DIR),  # this host's run folder, not the listening host's
            'renew_unseen': JOINED_RENEW_S}
    if info['agent_params'].get('links_log'):  # type: ignore[union-attr]
        here['links_log'] = str(out / LINKS_LOG_DIR)
    params = write_params(out / 'agent_params.yaml', {**info['agent_params'], **here})  # type: ignore[dict-item]
    (out / 'run.json').write_text(json.dumps({
        'domain_id': domain, 'discovery_server': address, 'join': address, 'maps': info['maps'], 'ids': ids,
        'secure': secured}, indent=1))
    logs = out / 'logs'
    logs.mkdir(exist_ok=True)
    groups = [ids[k:k + agents_per_process] for k in range(0, len(ids), agents_per_process)]
    agents: list[ForkedAgent] = []
    interrupted = False

    def on_signal(signum: int, frame: object) -> None:
        nonlocal interrupted
        interrupted = True

    old = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        print(f'uav-flock agents: MAPs {ids[0]}-{ids[-1]} ({len(ids)}) in {len(groups)} processes join the run at '
              f'{address} (ROS_DOMAIN_ID={domain}{", TCP with TLS" if keys else ""}); logs in {logs}', flush=True)
        start_agents(groups, params, env, logs, agents, lambda: interrupted)
        write_pid_table(out / 'pids.json', {i: a.pid for g, a in zip(groups, agents) for i in g})
        while not interrupted and any(a.poll() is None for a in agents):
            time.sleep(POLL_S)
    finally:
        stop(agents)
        for sig, handler in old.items():
            signal.signal(sig, handler)
    codes = [a.poll() for a in agents]
    if interrupted:
        print('uav-flock agents: interrupted; every agent process of this host ended', flush=True)
        return 130
    failed = [g[0] for g, c in zip(groups, codes) if c not in (0, None, -TEARDOWN_SIGNAL)]
    hung = [g[0] for g, c in zip(groups, codes) if c == -TEARDOWN_SIGNAL]
    print(f'uav-flock agents: the run ended; {len(groups) - len(failed)} of {len(groups)} processes ended cleanly'
          + (f' ({len(hung)} left their DDS participant behind at teardown: {hung})' if hung else '')
          + (f' (see {logs}/agents_<first id>.log for {failed})' if failed else ''), flush=True)
    return 0 if not failed else 1
