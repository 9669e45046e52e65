"""A multirotor no one here modelled (`vehicle: {model: x500}`, docs/vehicle.md): crazyflow's Holybro X500
(`hb_x500`, its fitted attitude dynamics with rotor drag) flown by crazyflow's Mellinger position controller.

Each step the MAP's commanded horizontal acceleration is flown on into the controller's setpoints (the velocity it
leads to within v_max and the position that implies), from where the setpoints were, but never more than
LEAD_DISTANCE and LEAD_SPEED ahead of the truth: the controller's own feedback then holds off a steady wind, as
an autopilot's integrator does, and a command the airframe cannot follow winds up no further. The height is the
one the MAP was released at: the formation is flat (eq. 9 never commands a climb on the first-order multirotor),
and the altitude hold keeps it so. The airframe's state after the step's physics (100 Hz) is the truth. The wind
of the profile pushes it through its drag, and its GNSS error and power are the first-order multirotor's
(Multirotor's draws, from the same stream). Every MAP is a world of its own: crazyflow builds a thousand worlds
of one drone in seconds and one world of a thousand drones in a minute, and the MAPs keep their distance
themselves.

crazyflow sets SCIPY_ARRAY_API=1 for its process and computes in float32 unless told otherwise: a run on this
airframe is a process of its own (airframes.isolated), in float64, and each step's command is a fresh array.
"""
from __future__ import annotations

import contextlib
import io
import os
import sys
import warnings
from typing import Optional

import numpy as np
from numpy.typing import NDArray

from uav_agent.core.envelope import saturate
from uav_agent.core.params import FlockParams

from ..vehicle import Vehicle
from .multirotor import DRAG, Multirotor

F64 = NDArray[np.float64]
PHYSICS_HZ = 100  # crazyflow's physics and its position controller, per second
LEAD_DISTANCE, LEAD_SPEED = 3.0, 2.0  # m, m/s: how far the setpoints may lead the truth (the autopilot's windup)


class X500:
    """Every MAP of a run as crazyflow's hb_x500, each in a world of its own."""

    exact = False
    # The lag of its acceleration behind a command, measured (docs/vehicle.md, "The X500"): 63 % within 0.25 s.
    # v_max and a_max stay the profile's: the position controller's limits, as an autopilot is configured.
    PROFILE = {'tau': 0.25}
    ENVIRONMENT = {'SCIPY_ARRAY_API': '1'}
    NEEDS = 'crazyflow'
    INSTALL = './uav-flock bootstrap --with x500'

    def __init__(self, v: Vehicle, n: int, dt: float, rng: np.random.Generator) -> None:
        if os.environ.get('SCIPY_ARRAY_API') != '1':
            raise RuntimeError('vehicle x500: this process imported scipy without SCIPY_ARRAY_API=1, which crazyflow '
                               'needs: fly it through `uav-flock sim`, `up` or `study`, which start such a process')
        try:  # MuJoCo's MJX prints to stdout that it found no GPU backend (warp): stdout is the run's report
            with contextlib.redirect_stdout(io.StringIO()):
                import jax
                from crazyflow.control import Control
                from crazyflow.drones import Drone
                from crazyflow.dynamics import Dynamics
                from crazyflow.sim import Sim
        except ImportError as e:
            raise RuntimeError(f'vehicle x500 needs crazyflow, which is not installed ({e}): {self.INSTALL}') from None
        import mujoco
        mujoco.set_mju_user_warning(_warning)  # to stderr, not a MUJOCO_LOG.TXT in the folder it is run from
        jax.config.update('jax_enable_x64', True)
        self.jnp = jax.numpy
        self.v, self.dt, self.n = v, dt, n
        self.noise = Multirotor(v, n, dt, rng)  # gusts and GNSS errors, drawn as the first-order multirotor draws them
        self.ticks = max(int(round(dt * PHYSICS_HZ)), 1)
        with warnings.catch_warnings():
            warnings.filterwarnings('ignore', message=KNOWN[0])
            self.sim = Sim(n_worlds=max(n, 1), n_drones=1, drone=Drone.hb_x500, dynamics=Dynamics.so_rpy_rotor_drag,
                           control=Control.state, freq=PHYSICS_HZ, state_freq=PHYSICS_HZ, attitude_freq=PHYSICS_HZ,
                           body_rate_freq=PHYSICS_HZ, force_torque_freq=PHYSICS_HZ)

    def _place(self, q: F64, p: F64) -> None:
        """Every MAP's true position and velocity, as the airframe's state (q, p: all n MAPs)."""
        states = self.sim.data.states
        self.sim.data = self.sim.data.replace(states=states.replace(
            pos=self.jnp.asarray(np.array(q, dtype=np.float64)[:, None, :]),
            vel=self.jnp.asarray(np.array(p, dtype=np.float64)[:, None, :])))

    def release(self, q: F64, p: F64, centre: tuple[float, float], half_width: float,
                rng: np.random.Generator) -> tuple[F64, F64]:
        """The multirotor's release (no two nearer than they keep, none faster than v_max), placed in the worlds."""
        q, p = self.noise.release(q, p, centre, half_width, rng)
        self.altitude = np.array(q[:, 2], dtype=np.float64)  # the height its altitude hold keeps
        # The horizontal setpoints: the commands flown on from where they led, within LEAD of the truth.
        self.ref_q, self.ref_p = np.array(q[:, :2], dtype=np.float64), np.array(p[:, :2], dtype=np.float64)
        self._place(q, p)
        return q, p

    def estimate(self, rows: NDArray[np.intp], q: F64) -> F64:
        return self.noise.estimate(rows, q)

    def power(self, rows: NDArray[np.intp], p: F64) -> F64:
        return self.noise.power(rows, p)

    def traffic(self, truth: F64, told: F64, p: F64, fp: FlockParams) -> Optional[NDArray[np.intp]]:
        return self.noise.traffic(truth, told, p, fp)

    def step(self, rows: NDArray[np.intp], q: F64, p: F64, u: F64) -> tuple[F64, F64]:
        """The setpoints of the command u, a step of crazyflow's physics, the wind's push; then the draws move on.
        A MAP no longer flying holds where it is."""
        v, dt = self.v, self.dt
        states = self.sim.data.states
        pos = np.asarray(states.pos, dtype=np.float64)[:, 0, :]  # where a MAP no longer flying holds
        a = saturate(np.asarray(u, dtype=np.float64), v.a_max)
        cmd = np.zeros((self.n, 1, 16))
        cmd[:, 0, 0:3] = pos
        cmd[:, 0, 12] = 1.0  # level, facing +x
        ref_p = saturate(self.ref_p[rows] + a[:, :2] * dt, v.v_max)
        ref_q = self.ref_q[rows] + 0.5 * (self.ref_p[rows] + ref_p) * dt
        ref_p = p[:, :2] + saturate(ref_p - p[:, :2], LEAD_SPEED)  # no further ahead of the truth than LEAD_*
        ref_q = q[:, :2] + p[:, :2] * dt + saturate(ref_q - q[:, :2] - p[:, :2] * dt, LEAD_DISTANCE)
        self.ref_q[rows], self.ref_p[rows] = ref_q, ref_p
        cmd[rows, 0, 0:2] = ref_q
        cmd[rows, 0, 2] = self.altitude[rows]
        cmd[rows, 0, 3:5] = ref_p
        cmd[rows, 0, 6:8] = a[:, :2]
        self.sim.state_control(self.jnp.asarray(cmd))  # a fresh array each step: one changed in place is not safe
        self.sim.step(self.ticks)
        states = self.sim.data.states
        pos, vel = np.array(states.pos, dtype=np.float64)[:, 0, :], np.array(states.vel, dtype=np.float64)[:, 0, :]
        push = np.zeros_like(vel)
        push[:, :2] = DRAG * (self.noise.mean_wind + self.noise.gust)  # the wind's drag, over the step
        pos[rows] += 0.5 * push[rows] * dt * dt
        vel[rows] += push[rows] * dt
        self._place(pos, vel)
        self.noise.drift()
        return pos[rows], vel[rows]


KNOWN = ('Attaching a spec with an empty prefix',)  # crazyflow builds its worlds so: nothing to act on


def _warning(text: str) -> None:
    """MuJoCo's warnings, on stderr as one line each; those crazyflow's own scene always raises left out."""
    if not text.startswith(KNOWN):
        print(f'mujoco: {text.strip()}', file=sys.stderr, flush=True)
