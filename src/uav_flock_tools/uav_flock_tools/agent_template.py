"""The template every agent process of `up` is forked from: the agent imported, and inspect's module map.

Imported once, by the forkserver process that `up` forks its agent processes from (spawn.start_agents).
"""
import inspect

import uav_agent.agent_process  # noqa: F401  (the node, rclpy, numpy, scipy and the message types come with it)

# rclpy's logger finds each log call's caller with inspect, whose first use maps every loaded module to its
# file: 70 ms of realpath calls, paid again by every process. Done here once, every fork inherits the map.
inspect.getframeinfo(inspect.currentframe())
