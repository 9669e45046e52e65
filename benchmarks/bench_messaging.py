"""The messaging floor of a realtime run: what its ROS traffic alone costs in CPU, with no flocking computed.

Run: ./uav-flock exec python benchmarks/bench_messaging.py [--maps 90] [--per-process 10] [--neighbours 8]
[--seconds 20] [--rate 1]

The processes of `up --sync realtime` without their mathematics: one world process publishes every MAP's
sensing at 10 Hz × rate and takes their commands; agent processes host the MAP nodes, each of which, on its
sensing, publishes its state and a command, and takes the states of a fixed set of neighbours (ids i ± 1 ..
i ± neighbours/2). Messages, topics, QoS profiles and executor are the ones the runtime uses
(uav_flock_ros), and the states carry gossip of the size a drifting run carries. Every process measures its
own CPU time over the same window, after discovery has settled.

It answers one question: how much of the 2 cores a realtime run of this many MAPs has is taken before any
MAP computes anything. bench_runtime.py gives the CPU per MAP-step of the real run to set beside it.
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import resource
import sys
import time
from typing import Any

WARM_S = 8.0  # discovery of a hundred endpoints settles well within this on two cores
STEP_S = 0.1  # the shipped scenarios' Δt


def cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def world(maps: int, rate: float, seconds: float, out: Any) -> None:
    import numpy as np
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from std_msgs.msg import Header
    from uav_flock_msgs.msg import Command, Sensing
    from uav_flock_ros import convert
    from uav_flock_ros.executors import make_executor
    from uav_flock_ros.qos import LATEST_QOS, STEP_QOS

    rclpy.init()
    node = rclpy.create_node('world_sim')
    pubs = [node.create_publisher(Sensing, f'/map_{i}/sensing', STEP_QOS) for i in range(maps)]
    heard = [0]
    step = [0]

    def on_cmd(msg: Command) -> None:
        if convert.CommandData.from_msg(msg).step == step[0]:
            heard[0] += 1

    for i in range(maps):
        node.create_subscription(Command, f'/map_{i}/cmd', on_cmd, LATEST_QOS)
    rng = np.random.default_rng(0)
    q = rng.uniform(-100, 100, (maps, 3))

    def tick() -> None:
        step[0] += 1
        hdr = Header(frame_id='world')
        for i, pub in enumerate(pubs):
            near = np.array([(i + k) % maps for k in (-4, -3, -2, -1, 1, 2, 3, 4)])
            pub.publish(convert.SensingData(i, step[0], q[i], q[i] * 0.01, 12, 0.5, np.sort(near),
                                            np.full(len(near), 18.0), 1).to_msg(hdr))

    node.create_timer(STEP_S / rate, tick)
    executor = make_executor()
    executor.add_node(node)
    start = time.monotonic()
    window: list[float] = []
    try:
        while time.monotonic() - start < WARM_S + seconds:
            if not window and time.monotonic() - start >= WARM_S:
                window = [cpu_s(), float(step[0]), float(heard[0])]
            executor.spin_once(timeout_sec=0.05)
    except ExternalShutdownException:
        pass
    out.put(('world', cpu_s() - window[0], step[0] - window[1], heard[0] - window[2]))
    rclpy.try_shutdown()


def agents(ids: list[int], maps: int, neighbours: int, seconds: float, out: Any) -> None:
    import numpy as np
    import rclpy
    from rclpy.node import Node
    from uav_flock_msgs.msg import AgentState, Command, Sensing
    from uav_flock_ros import convert
    from uav_flock_ros.executors import make_executor
    from uav_flock_ros.qos import LATEST_QOS, LATEST_STATE_READ_QOS, STATE_QOS, STEP_QOS

    rclpy.init()
    half = neighbours // 2
    seen = [(64 + 64 * a + a + 1, 0) for a in range(4)] + [(k, 0) for k in range(5)]  # nine roles heard of

    class Map(Node):
        def __init__(self, i: int) -> None:
            super().__init__(f'uav_agent_{i}', namespace=f'map_{i}')
            self.i = i
            self.state_pub = self.create_publisher(AgentState, 'state', STATE_QOS)
            self.cmd_pub = self.create_publisher(Command, 'cmd', STEP_QOS)
            self.create_subscription(Sensing, 'sensing', self.on_sensing, LATEST_QOS)
            self.heard = 0
            for k in [*range(-half, 0), *range(1, half + 1)]:
                self.create_subscription(AgentState, f'/map_{(i + k) % maps}/state', self.on_state,
                                         LATEST_STATE_READ_QOS)

        def on_sensing(self, msg: Sensing) -> None:
            s = convert.SensingData.from_msg(msg)
            told = tuple((c, s.step) for c, _ in seen)
            self.state_pub.publish(convert.AgentStateData(self.i, s.step, s.q, s.p, s.n_users, 1, 2, (1, 2), (0, 1, 2),
                                                          told, (), ((129, 1),), False).to_msg(msg.header))
            self.cmd_pub.publish(convert.CommandData(self.i, s.step, np.zeros(3), 1, 2).to_msg(msg.header))

        def on_state(self, msg: AgentState) -> None:
            convert.AgentStateData.from_msg(msg)
            self.heard += 1

    nodes = [Map(i) for i in ids]
    executor = make_executor()
    for n in nodes:
        executor.add_node(n)
    start = time.monotonic()
    window: list[float] = []
    while time.monotonic() - start < WARM_S + seconds:
        if not window and time.monotonic() - start >= WARM_S:
            window = [cpu_s(), float(sum(n.heard for n in nodes))]
        executor.spin_once(timeout_sec=0.05)
    out.put(('agents', cpu_s() - window[0], 0.0, sum(n.heard for n in nodes) - window[1]))
    rclpy.try_shutdown()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--maps', type=int, default=90)
    ap.add_argument('--per-process', type=int, default=10)
    ap.add_argument('--neighbours', type=int, default=8, help='states each MAP takes (default: 8)')
    ap.add_argument('--seconds', type=float, default=20.0, help='measured window after discovery (default: 20)')
    ap.add_argument('--rate', type=float, default=1.0, help='steps per Δt of wall time (default: 1)')
    a = ap.parse_args()
    if a.maps < a.neighbours + 1 or a.per_process < 1 or a.seconds <= 0 or a.rate <= 0:
        ap.error('need maps > neighbours, per-process >= 1, seconds > 0, rate > 0')
    from uav_flock_tools.domains import claim_domain, ros_env
    with claim_domain() as domain:
        os.environ.update(ros_env(domain))
        ctx = mp.get_context('spawn')
        out = ctx.Queue()
        groups = [list(range(k, min(k + a.per_process, a.maps))) for k in range(0, a.maps, a.per_process)]
        procs = [ctx.Process(target=world, args=(a.maps, a.rate, a.seconds, out))]
        procs += [ctx.Process(target=agents, args=(g, a.maps, a.neighbours, a.seconds, out)) for g in groups]
        print(f'{a.maps} MAPs in {len(groups)} agent processes and a world, {a.neighbours} neighbours each, '
              f'{WARM_S:.0f} s of discovery then {a.seconds:.0f} s measured ...', file=sys.stderr, flush=True)
        for p in procs:
            p.start()
        said = [out.get(timeout=WARM_S + a.seconds + 120) for _ in procs]
        for p in procs:
            p.join(timeout=30)
    world_cpu = sum(c for kind, c, _, _ in said if kind == 'world')
    agent_cpu = sum(c for kind, c, _, _ in said if kind == 'agents')
    steps = next(s for kind, _, s, _ in said if kind == 'world')
    commands = next(h for kind, _, _, h in said if kind == 'world')
    states = sum(h for kind, _, _, h in said if kind == 'agents')
    map_steps = steps * a.maps
    print(f'steps sent: {steps:.0f} in {a.seconds:.0f} s ({steps / a.seconds:.1f} /s); commands of the current step '
          f'heard: {100 * commands / max(map_steps, 1):.0f} %; states taken: {states / max(map_steps, 1):.1f} per MAP-step')
    print(f'CPU, s per s of wall time: agents {agent_cpu / a.seconds:.2f}, world {world_cpu / a.seconds:.2f}, '
          f'all {(agent_cpu + world_cpu) / a.seconds:.2f} (of {os.cpu_count()} cores)')
    print(f'CPU per MAP-step: agents {1e3 * agent_cpu / max(map_steps, 1):.2f} ms, '
          f'world {1e3 * world_cpu / max(map_steps, 1):.2f} ms')
    return 0


if __name__ == '__main__':
    sys.exit(main())
