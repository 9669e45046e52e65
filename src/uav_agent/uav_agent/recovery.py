"""What a MAP's node does when a lockstep step stalls on DDS, or the world is gone (mixed into AgentNode).

A step waits for the states of exactly its listed neighbours; on a busy DDS graph some never come in
without help: samples the executor was not told of are taken by hand, readers are made anew, and a
process whose start stalls makes its participant anew (agent_process.AgentProcess.renew, on stuck_at_start
and unseen_at_start, or mid-run on stuck_midway, its MAPs carried over). A MAP that no longer sees world_sim ends on
its own.
"""
from __future__ import annotations

import os
import time
from typing import Any, Optional

from rclpy.subscription import Subscription
from uav_flock_msgs.msg import AgentState
from uav_flock_ros import convert
from uav_flock_ros.executors import take_waiting

WATCH_PERIOD_S = 1.0
WORLD_WAIT_NOTE_S = 5.0  # no world on the graph for this long at start: the node says it waits, once
WORLD_TIMEOUT_S = 10.0  # no sensing and no world on the graph for this long (after it was seen): it is gone
# lockstep: a reader that has heard nothing of a listed neighbour this long after the step's sensing (the
# world re-sends a stalled step's sensing every 2 s, and each repeat makes the neighbour publish its state
# again) is made anew: with a discovery server and ~90 processes, the writer of a new reader can go on
# never learning of it. Then again after twice as long, and so on. Step 0, when the whole graph is being
# discovered at once, gets longer.
RESUBSCRIBE_AFTER_S = 5.0
RESUBSCRIBE_AFTER_FIRST_S = 20.0
# lockstep: how often a step that waits looks into its silent neighbours' readers itself. The events
# executor is not told of some samples that reach readers made in a burst (hundreds at once as MAPs
# spread); they would otherwise sit there until the 1 s watch found them.
SWEEP_PERIOD_S = 0.25
# lockstep, step 0: a process whose MAP has heard nothing this long of a neighbour whose writer is matched, after
# its readers were made anew, makes its DDS participant anew (AgentProcess.renew). Fast DDS 2.14's TCP transport
# (`--secure`) can leave a connection between two participants open with a logical port that failed its
# negotiation and is never asked for again: both ends matched, no sample ever crosses (seen in 1 of 8 starts of
# 30 MAPs at 2 a process). Nothing of a run is held before step 0, so a new participant loses nothing, and it
# opens new connections. Before any sensing, a process that has not seen world_sim on the graph renew_unseen s
# after its nodes were made (AgentNodeParams) does so too: a refused handshake with the discovery server left two
# MAPs' process unknown to the run, 28 of 30 MAPs ready for 150 s (1 of 15 starts of 30 MAPs at 2 a process).
RENEW_AFTER_S = 30.0
# lockstep, past step 0: the same fault met when two MAPs first become neighbours mid-run. In a secured run whose
# discovery server had been restarted, MAPs 2 and 4 of 8, neighbours from step 17 on, each had the other's writer
# matched and heard nothing of it, their readers made anew 6 times, for 180 s (1 of 3 runs of that test). A process
# whose MAP still hears nothing of a matched writer after its readers were made anew this many times makes its
# participant anew too, and its MAPs go on where they were (AgentNode.carry): 20 s into the stall.
RENEW_MIDWAY_TRIES = 2


class Recovery:
    """The watch, the sweep and the recovery of an AgentNode: they read and renew the node's step and readers."""

    # The AgentNode's, which these methods use (agent_node.py).
    pending: Optional[convert.SensingData]
    sensed_at: float
    step: int
    failed: bool
    realtime: bool
    stopped: bool
    world_seen: bool
    world_start_timeout: float
    renew_unseen: float
    next_report: float
    silent_writers: bool
    resubscribed: tuple[int, int]
    map_id: int
    clusters: Any
    latest: dict[int, convert.AgentStateData]
    neighbour_subs: dict[int, Subscription]

    def sweep(self) -> None:
        """Take what already sits in the readers of the neighbours a waiting step still misses."""
        s = self.pending
        if s is None or time.monotonic() - self.sensed_at < SWEEP_PERIOD_S:
            return
        for j in [j for j in self.unheard(s) if j in self.neighbour_subs]:
            if self.pending is not s or j not in self.neighbour_subs:
                break  # a taken sample completed the step
            self.take_waiting_of(j)

    def watch_world(self) -> None:
        """Say what a stuck step waits for; end on our own when the world is gone."""
        if self.failed:
            return  # silent: nothing to wait for, and a crashed node has no handles to ask the graph with
        silent = time.monotonic() - self.sensed_at
        if self.pending is not None and silent > 2.0:
            missing = {j: (self.latest[j].step if j in self.latest else None) for j in self.unheard(self.pending)}
            matched = {j: (self.neighbour_subs[j].get_publisher_count(), self.count_publishers(f'/map_{j}/state'))
                       for j in missing if j in self.neighbour_subs}
            if silent >= self.next_report:  # 2 s, 4 s, 8 s, ... into the step: a log, not a flood
                self.next_report = 2 * silent
                self.get_logger().info(f'step {self.pending.step}: waiting {silent:.0f} s for neighbours '
                                          f'(id: last step heard) {missing}, (id: writers matched, listed) '
                                          f'{matched}, clusters known: {self.clusters is not None}')
            self.silent_writers = any(m > 0 for m, _ in matched.values())
            if not self.realtime:
                self.recover(silent, {j: m for j, (m, listed) in matched.items() if m > 0 or listed > 0})
        else:
            self.silent_writers = False
        world_listed = self.count_publishers(f'/map_{self.map_id}/sensing') > 0
        self.world_seen = self.world_seen or world_listed
        if not self.world_seen and silent > WORLD_WAIT_NOTE_S and not getattr(self, 'said_waiting', False):
            self.said_waiting = True  # once: a node started by hand before its world should not look hung
            self.get_logger().info(f'MAP {self.map_id}: waiting for world_sim (ROS_DOMAIN_ID='
                                   f'{os.environ.get("ROS_DOMAIN_ID", "0")}), for {self.world_start_timeout:g} s at most')
        if not self.world_seen and silent > self.world_start_timeout:
            self.get_logger().error(f'no world_sim appeared within {silent:.0f} s: stopping MAP {self.map_id}')
            self.stopped = True
        elif self.world_seen and silent > WORLD_TIMEOUT_S and not world_listed:
            self.get_logger().error(f'no world_sim for {silent:.0f} s: stopping MAP {self.map_id}')
            self.stopped = True

    def recover(self, silent: float, silent_writers: dict[int, int]) -> None:
        """Get a stalled step going again, when the neighbours it waits for exist but are not heard.

        First, samples that sit in a reader without the executor having been told of them are taken by
        hand. Should that find nothing, the readers are made anew, RESUBSCRIBE_AFTER_S after the step's
        sensing, then after twice as long, and so on.
        """
        taken = 0
        for j, matched in silent_writers.items():
            if matched and self.pending is not None:
                taken += self.take_waiting_of(j)
        if taken:
            self.get_logger().info(f'took {taken} state samples of {list(silent_writers)} by hand '
                                      'that the executor had not delivered')
            return
        tries = self.resubscribed[1] if self.resubscribed[0] == self.step else 0
        wait = RESUBSCRIBE_AFTER_FIRST_S if self.step == 0 else RESUBSCRIBE_AFTER_S
        if silent_writers and silent > wait * 2 ** tries and self.pending is not None:
            self.resubscribed = (self.step, tries + 1)
            for j in silent_writers:
                self.subscribe(j)
            self.get_logger().info(f'step {self.pending.step}: subscribed anew to the states of '
                                      f'{list(silent_writers)}')

    def stuck_at_start(self) -> bool:
        """Step 0 waits, RENEW_AFTER_S after its sensing, on a neighbour whose writer is matched but unheard,
        its readers made anew already: the connection between the two participants carries nothing."""
        return (not self.realtime and self.step == 0 and self.pending is not None and self.silent_writers
                and self.resubscribed[0] == 0 and time.monotonic() - self.sensed_at > RENEW_AFTER_S)

    def stuck_midway(self) -> bool:
        """A step past 0 waits on a neighbour whose writer is matched but unheard, its readers made anew
        RENEW_MIDWAY_TRIES times this step already: the connection between the two participants carries nothing."""
        return (not self.realtime and self.step > 0 and self.pending is not None and self.silent_writers
                and self.resubscribed[0] == self.step and self.resubscribed[1] >= RENEW_MIDWAY_TRIES
                and time.monotonic() - self.sensed_at > RESUBSCRIBE_AFTER_S * 2 ** RENEW_MIDWAY_TRIES)

    def unseen_at_start(self) -> bool:
        """No sensing yet, and no world_sim on the graph renew_unseen s after this node was made: this
        participant is cut off from discovery."""
        return (self.renew_unseen > 0 and self.step < 0 and not self.world_seen
                and time.monotonic() - self.sensed_at > self.renew_unseen)

    def take_waiting_of(self, j: int) -> int:
        """Take what sits in neighbour j's reader, as the executor itself would (rclpy's own take call)."""
        def handle(msg: AgentState) -> bool:
            self.on_state(j, msg)
            return j in self.neighbour_subs  # the sample may have made us step and drop j

        return take_waiting(self.neighbour_subs[j], handle)
