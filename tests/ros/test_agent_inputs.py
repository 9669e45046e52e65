"""One real agent node, driven over DDS from the test: what it makes of late copies of past steps."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import rclpy
from geometry_msgs.msg import Point, Vector3
from std_msgs.msg import Int64
from uav_agent.core.params import FlockParams
from uav_flock_ros.processes import write_params
from uav_flock_ros.qos import LATCHED_QOS, STATE_QOS, STEP_QOS
from uav_flock_msgs.msg import AgentState, Clusters, Command, NeighborList, Sensing


def wait(node: rclpy.node.Node, until, timeout: float, what: str) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout
    while not until():
        assert time.monotonic() < deadline, f'{what} within {timeout} s'
        rclpy.spin_once(node, timeout_sec=0.05)


def test_late_copies_of_past_steps_are_counted_not_warned(tmp_path: Path, ros_env: dict[str, str]) -> None:
    """A neighbour's state of step 0 arriving again after step 1 is normal on a busy DDS: no warning in a
    healthy run, and the count in the log at the end."""
    params = write_params(tmp_path / 'params.yaml', {**FlockParams().as_dict(), 'sync': 'lockstep'})
    agent = subprocess.Popen([sys.executable, '-m', 'uav_agent.agent_process', '--ids', '0', '--ros-args',
                              '--params-file', str(params)], env=ros_env, stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True)
    rclpy.init()
    try:
        node = rclpy.create_node('driver')
        commands: dict[int, Command] = {}
        node.create_subscription(Command, '/map_0/cmd', lambda m: commands.__setitem__(int(m.step), m), STEP_QOS)
        clusters = node.create_publisher(Clusters, '/clusters', LATCHED_QOS)
        sensing = node.create_publisher(Sensing, '/map_0/sensing', STEP_QOS)
        neighbour = node.create_publisher(AgentState, '/map_1/state', STATE_QOS)
        finished = node.create_publisher(Int64, '/events/finished', LATCHED_QOS)
        clusters.publish(Clusters(centroids=[Point(x=0.0, y=0.0), Point(x=100.0, y=0.0)], sizes=[10, 10],
                                  radii=[30.0, 30.0]))
        wait(node, lambda: sensing.get_subscription_count() > 0, 60, 'the agent subscribes to its sensing')

        def state_of_1(step: int) -> AgentState:
            return AgentState(id=1, step=step, position=Point(x=10.0, y=0.0, z=20.0), velocity=Vector3())

        for k in (0, 1):
            sensing.publish(Sensing(id=0, step=k, position=Point(x=0.0, y=0.0, z=20.0), velocity=Vector3(),
                                    neighbors=NeighborList(ids=[1])))
            wait(node, lambda: neighbour.get_subscription_count() > 0, 30, 'the agent follows its neighbour')
            neighbour.publish(state_of_1(k))
            wait(node, lambda k=k: k in commands, 30, f'the agent answers step {k}')
        neighbour.publish(state_of_1(0))  # a late copy of step 0, after step 1
        time.sleep(0.5)
        rclpy.spin_once(node, timeout_sec=0.1)
        finished.publish(Int64(data=2))
        out, _ = agent.communicate(timeout=60)
        node.destroy_node()
    finally:
        rclpy.try_shutdown()
        if agent.poll() is None:
            agent.kill()
    assert agent.returncode == 0, out
    assert 'WARN' not in out and 'rejected' not in out, out
    assert 'ignored 1 late copies of past steps (1 from neighbour states)' in out, out


def test_a_node_process_stuck_at_teardown_in_a_call_that_holds_the_gil_still_goes(tmp_path: Path) -> None:
    """The teardown's own timer needs the GIL; a DDS teardown that holds it (seen on a joining host of a secured
    run, and of world_sim after its recorder was killed) is ended by the kernel with TEARDOWN_SIGNAL, after the
    threads' tracebacks are in the log. Agents and world_sim both leave by processes.leave_after."""
    from uav_flock_ros.processes import TEARDOWN_SIGNAL
    code = ('from uav_flock_ros.processes import leave_after; import ctypes; leave_after(0, \'node\', 0.5); '
            'ctypes.PyDLL(None).sleep(60)')  # libc's sleep, called without releasing the GIL
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=50)
    assert done.returncode == -TEARDOWN_SIGNAL, (done.returncode, done.stderr)
    assert 'Current thread' in done.stderr or 'Thread' in done.stderr, done.stderr  # faulthandler's dump
