"""Moving walls: planes and obstacles that translate as given functions of time, or float.

A moving wall keeps its shape and orientation; its reference point (a plane's point, an obstacle's
centre, a mesh's distance grid) is displaced by

    X(t) = V t + A (sin(omega t + phi) - sin(phi)),        omega = 2 pi f

so X(0) = 0: the scene gives where the wall is at t = 0. V (m/s) is a constant velocity, A (m) the
amplitude of an oscillation of frequency f (Hz) and phase phi (degrees in the scene). Its velocity
and acceleration are

    u_w(t) = V + A omega cos(omega t + phi),        a_w(t) = -A omega^2 sin(omega t + phi).

The walls' terms use both (sphcore/physics/walls.py): the no-slip viscous wall drags the fluid towards
u_w instead of rest (Morris, Fox & Zhu 1997 with the wall's velocity), the pressure extrapolated
behind a wall uses the body force in the wall's frame, b - a_w (Adami, Hu & Adams 2012, eq. 27), and
the collision guard reflects the velocity relative to the wall. A plane moving along itself (a
Couette plate, a cavity lid) is not displaced as far as the fluid can tell, but drags it.

Every peer evaluates X(t), u_w(t), a_w(t) from the same t in float64, so all peers move their walls
to the same bits; a resumed run moves them to its checkpoint's t. A ``FloatingBody`` answers the
same three questions from its state instead of from t: the fluid moves it (two-way coupling).
Rotation and tabulated motion are not available yet.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Motion:
    """One wall's prescribed translation (module docstring); vectors are (3,) float64."""
    velocity: np.ndarray     # V (m/s)
    amplitude: np.ndarray    # A (m)
    omega: float             # 2 pi f (rad/s)
    phase: float             # phi (rad)

    @classmethod
    def of(cls, item) -> "Motion | None":
        """The motion of a scene item with velocity, amplitude, frequency and phase keys (a plane,
        an obstacle); None if it does not move."""
        velocity = np.zeros(3)
        velocity[: len(item.velocity)] = item.velocity
        amplitude = np.zeros(3)
        amplitude[: len(item.amplitude)] = item.amplitude
        if not velocity.any() and not (amplitude.any() and item.frequency > 0.0):
            return None
        return cls(velocity, amplitude, 2.0 * math.pi * item.frequency, math.radians(item.phase))

    def displacement(self, t: float) -> np.ndarray:
        """X(t) (m)."""
        return self.velocity * t + self.amplitude * (math.sin(self.omega * t + self.phase) - math.sin(self.phase))

    def wall_velocity(self, t: float) -> np.ndarray:
        """u_w(t) (m/s)."""
        return self.velocity + self.amplitude * (self.omega * math.cos(self.omega * t + self.phase))

    def wall_acceleration(self, t: float) -> np.ndarray:
        """a_w(t) (m/s^2)."""
        return self.amplitude * (-self.omega ** 2 * math.sin(self.omega * t + self.phase))

    def largest_speed(self) -> float:
        """An upper bound of |u_w(t)| (m/s): the scene refuses walls as fast as sound."""
        return math.hypot(*self.velocity) + math.hypot(*self.amplitude) * self.omega  # hypot: no overflow


@dataclass
class FloatingBody:
    """A rigid obstacle moved by the fluid (two-way coupling), translating only: its wall row
    ``wall``, mass M (kg; kg/m in 2D) and the axes it may move along (``free``, 1 or 0). Each step
    the fluid's force on it is the reaction to the wall terms its wall exerts on the particles,

        F = - sum_i m_i (a_i^pressure + a_i^viscous)   (that wall's share of physics/walls.py),

    summed exactly (integers of ``quantum`` newtons) over all peers; then, by symplectic Euler like
    the fluid,

        a = free (F / M + b),   u += dt a,   X += dt u,

    b the body force of the fluid (gravity and forces.external, ramped alike). X, u and a are state:
    checkpoints carry them (sphcore/checkpoint.py "bodies"). The coupling is explicit (the force of
    step n moves the body for step n + 1), which is stable for bodies not much lighter than the fluid
    they displace (added mass); rotation is not modelled (the body keeps its orientation)."""
    wall: int
    mass: float
    free: np.ndarray                                          # (3,) 1.0 where the body may move
    x: np.ndarray = field(default_factory=lambda: np.zeros(3))  # X (m) from the scene's position
    v: np.ndarray = field(default_factory=lambda: np.zeros(3))  # u (m/s)
    a: np.ndarray = field(default_factory=lambda: np.zeros(3))  # a (m/s^2)
    force: np.ndarray = field(default_factory=lambda: np.zeros(3))  # the fluid's last force on it (N; N/m in 2D)

    STATE = ("x", "v", "a", "force")  # where it is and how it moves: not what the body is (solver._same)

    def displacement(self, t: float) -> np.ndarray:
        return self.x

    def wall_velocity(self, t: float) -> np.ndarray:
        return self.v

    def wall_acceleration(self, t: float) -> np.ndarray:
        return self.a

    def quantum(self, gravity) -> float:
        """The unit of the exact force sum (N): 2^-40 of the body's weight (or of M x 1 m/s^2)."""
        return self.mass * max(float(np.linalg.norm(gravity)), 1.0) * 2.0 ** -40

    def advance(self, force, body_acceleration, dt: float):
        """One step under the fluid's ``force`` and the body force (module docstring)."""
        self.force = np.asarray(force, dtype=np.float64)
        self.a = self.free * (self.force / self.mass + np.asarray(body_acceleration, dtype=np.float64))
        self.v = self.v + dt * self.a
        self.x = self.x + dt * self.v

    def state(self) -> list:
        """X, u, a as 9 floats (a checkpoint's "bodies" entry)."""
        return [float(c) for c in (*self.x, *self.v, *self.a)]

    def set_state(self, values):
        values = np.asarray(values, dtype=np.float64)
        self.x, self.v, self.a = values[0:3].copy(), values[3:6].copy(), values[6:9].copy()
