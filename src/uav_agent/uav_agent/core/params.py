"""Parameters of the control law and mode switch (paper Section V), plus the choices the paper leaves open."""
from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any, Callable

from .checks import bound, number

# Algorithm 2's open cases, where the paper is ambiguous, with their allowed values; docs/choices.md explains
# them. Which allocation runs is the other policy: its names are policies.ALLOCATIONS'.
OPEN_CHOICES: dict[str, tuple[str, ...]] = {
    'zero_users': ('move_on', 'static'),
    'm1_pending': ('hold', 'lead'),
    'm0_exhausted': ('bridge', 'serve'),
    'edge_choice': ('nearest', 'keep_nearest', 'share'),
}
# FlockParams fields a scenario sets from its other sections (`links:`, `vehicle:`), not from `flock:`
DERIVED = ('reach', 'hush', 'v_max', 'a_max', 'tau', 'keep', 'traffic')
SAFETY = ('rules', 'filter')  # FlockParams.safety's values
ENVELOPE = ('v_max', 'a_max', 'tau', 'keep', 'traffic')  # the vehicle's, 0 on the paper's (core/envelope.py)


@dataclass(frozen=True)
class FlockParams:
    """Everything one MAP needs to compute u_i and its mode. Units: m, s, users."""

    d: float = 20.0            # desired inter-MAP distance (m), eq. 11
    r: float = 24.0            # communication range (m), eq. 1 neighbours
    epsilon: float = 0.1       # sigma-norm parameter, eq. 7
    a: float = 5.0             # phi gain / overload gain, eq. 10-11
    b: float = 5.0             # phi gain, eq. 11
    gamma: float = 0.2         # bump cut-off of Phi, alpha_{gamma,1} in eq. 11 (paper silent)
    n_max: float = 80.0        # serving capacity N_max, eq. 10 and g
    c1: float = 0.3            # goal position gain, eq. 12
    c2: float = 0.6            # goal velocity gain, eq. 12-13
    k: float = 10.0            # connectivity potential gain, eq. 6 and 13
    r0: float = 0.95           # goal coverage threshold, Algorithm 2
    n0: int = 3                # serving threshold to M1, Algorithm 2
    n1: int = 10               # serving threshold to M2, Algorithm 2
    height: float = 20.0       # flight altitude H (m)
    allocation: str = 'demand'  # a name of policies.ALLOCATIONS; 'algorithm2': the paper's, with the four below
    zero_users: str = 'move_on'
    m1_pending: str = 'hold'
    m0_exhausted: str = 'bridge'
    edge_choice: str = 'keep_nearest'
    # How a multirotor MAP keeps its distance and its envelope: 'rules' (core/envelope.py's keep, swerve, priority
    # and brake's governor) or 'filter' (one safety filter, core/safety.py). Nothing on the paper's vehicle.
    safety: str = 'rules'
    # The longest link a MAP relies on (m), 0 for r: where the scenario's channel delivers half of what is
    # sent (links.reach). Set from its `links:` section, never in `flock:`.
    reach: float = 0.0
    # Steps a MAP takes a neighbour's silence for the channel's losses, not for its absence (links.hush):
    # 0 under the paper's channel, where silence is absence. Set from `links:` too.
    hush: int = 0
    # The envelope the MAP flies in (core/envelope.py), from the scenario's `vehicle:`; all 0 on the paper's
    # unbounded double integrator. Speed (m/s) and acceleration (m/s^2) over the ground, the autopilot's lag
    # (s), the least distance the MAP keeps from another: the vehicle's separation plus its GNSS margin (m), and
    # the range of its traffic receiver (m; 0: none), whose broadcasts rules keep and swerve then act on.
    v_max: float = 0.0
    a_max: float = 0.0
    tau: float = 0.0
    keep: float = 0.0
    traffic: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @property
    def link_reach(self) -> float:
        """The longest link a MAP relies on (m)."""
        return self.reach or self.r


def check(p: FlockParams, where: Callable[[str], str] = str,
          choices: dict[str, tuple[str, ...]] = OPEN_CHOICES) -> None:
    """Raise ValueError for values no run can use, naming the parameter as `where(name)` does.

    The scenario loader and the agent node both call it through policies.check, which adds the allocation's
    names to the choices: an agent started by hand with `-p r:=-1` is refused as a scenario with `flock.r: -1` is.
    """
    for f in fields(p):
        v = getattr(p, f.name)
        if f.name in choices:
            if v not in choices[f.name]:
                raise ValueError(f'{where(f.name)}: must be one of {", ".join(choices[f.name])}, got {v!r}')
        elif isinstance(f.default, str):
            continue  # a choice whose values another module names
        elif f.name == 'reach':
            number(v, where(f.name), low=0.0, high=p.r)
        elif f.name in ENVELOPE:
            number(v, where(f.name), low=0.0)
        elif isinstance(f.default, int):
            number(v, where(f.name), low=0, integer=True)
        else:
            number(v, where(f.name), low=0.0, low_open=True)
    if p.d >= p.r:
        raise ValueError(f'{where("d")}: must be below {where("r")} ({p.r}), got {p.d}')
    if p.a > p.b:
        raise ValueError(f'{where("a")}: must not exceed {where("b")} ({p.b}) or phi(0) != 0, got {p.a}')
    if p.gamma >= 1.0:
        raise ValueError(f'{where("gamma")}: must be below 1, got {p.gamma}')
    if p.n0 > p.n1:
        raise ValueError(f'{where("n0")}: must not exceed {where("n1")} ({p.n1}), got {p.n0}')
    if p.r0 > 1.0:
        raise ValueError(f'{where("r0")}: a coverage ratio, must be at most 1, got {p.r0}')


@dataclass(frozen=True)
class AgentNodeParams:
    """The agent node's own parameters, beside the FlockParams it also takes; checked by check_fields."""

    hysteresis: float = field(default=2.0, metadata=bound(low=0.0))  # m beyond r before a neighbour is dropped
    sync: str = 'lockstep'                                            # lockstep or realtime (uav_flock_ros.qos)
    # Many processes starting on few cores take a while to bring the world up: wait this long for it (s).
    world_start_timeout: float = field(default=120.0, metadata=bound(low=0.0, low_open=True))
    # A process that has not seen the world this long after its nodes were made makes its DDS participant anew,
    # at most 3 times (agent_process.AgentProcess): one cut off from discovery at start (s; 0: never).
    renew_unseen: float = field(default=60.0, metadata=bound(low=0.0))
    # Where `uav-flock kill` leaves a file named by a MAP id before it sends SIGUSR1: that MAP's node then ends
    # at once inside its process, as a crash would, while the process's other MAPs fly on ('' : none).
    crash_dir: str = ''
    # Realtime under a channel: each neighbour state that arrives, with the inputs of its decision and whether it
    # was heard, goes as a line into <links_log>/map_<id>.csv ('' : nowhere).
    links_log: str = ''
