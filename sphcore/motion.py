"""Prescribed motion of walls: planes and obstacles that translate as given functions of time.

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
to the same bits; a resumed run moves them to its checkpoint's t. Rotation and tabulated motion are
not available yet.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

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
        """An upper bound of |u_w(t)| (m/s), for the time step's speed estimate."""
        return float(np.linalg.norm(self.velocity) + np.linalg.norm(self.amplitude) * self.omega)
