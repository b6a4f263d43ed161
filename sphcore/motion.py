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

Or X(t) is a table (``Path``, the key ``path``): rows (t_k, X_k) joined by the monotone piecewise
cubic Hermite interpolant of Fritsch & Carlson (1980) on each axis, whose slopes are zero at the
first and last rows; before the first row and after the last the wall rests. So u_w is continuous
everywhere (no impulse into the fluid at a row, and none at the ends), the path never overshoots
the table between rows (a paddle does not pass its stops), and a_w is piecewise linear.

A wall may also turn about one fixed axis through its pivot P (the scene's ``pivot``, relative to
its reference point at t = 0), by the angle vector

    theta(t) = W t + B (sin(omega t + phi) - sin(phi))        (W, B parallel: one axis e)

with the same frequency and phase as the translation: R(t) is the rotation by theta . e about e
(Rodrigues), the wall's geometry is turned by R(t) about P and then displaced by X(t), and every
point r of it moves at

    u(r) = u_w + Omega x (r - P(t)),      a(r) = a_w + alpha x (r - P(t)) + Omega x (Omega x (r - P(t))),

Omega = theta', alpha = theta'', P(t) = P + X(t). The walls' terms evaluate u and a at the wall point
nearest the particle (physics/walls.py ``wall_point_velocity``); a wall that only translates has
Omega = alpha = 0 there and computes what it did before rotation existed. A path or a floating body
does not turn. A floating body turns as the fluid's torque drives it, about the axes its scene frees
(``FloatingBody`` below).

Every peer evaluates X(t), u_w(t), a_w(t) (and R, Omega, alpha) from the same t in float64, so all
peers move their walls to the same bits; a resumed run moves them to its checkpoint's t. A
``FloatingBody`` answers the same questions from its state instead of from t: the fluid moves it
(two-way coupling).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


def rotation_matrix(degrees) -> np.ndarray:
    """R = Rz @ Ry @ Rx for rotations about x, then y, then z (degrees); local -> world."""
    ax, ay, az = (math.radians(a) for a in degrees)
    cx, sx, cy, sy, cz, sz = math.cos(ax), math.sin(ax), math.cos(ay), math.sin(ay), math.cos(az), math.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


class _NoRotation:
    """What a wall that does not turn answers (a path, a floating body)."""
    rotates = False
    pivot = np.zeros(3)

    def rotation(self, t: float) -> np.ndarray:
        return np.eye(3)

    def angular_velocity(self, t: float) -> np.ndarray:
        return np.zeros(3)

    def angular_acceleration(self, t: float) -> np.ndarray:
        return np.zeros(3)


def _vector(values) -> np.ndarray:
    out = np.zeros(3)
    out[: len(values)] = values
    return out


@dataclass(frozen=True)
class Motion:
    """One wall's prescribed translation and rotation (module docstring); vectors are (3,) float64."""
    velocity: np.ndarray     # V (m/s)
    amplitude: np.ndarray    # A (m)
    omega: float             # 2 pi f (rad/s)
    phase: float             # phi (rad)
    spin: np.ndarray = field(default_factory=lambda: np.zeros(3))            # W (rad/s)
    spin_amplitude: np.ndarray = field(default_factory=lambda: np.zeros(3))  # B (rad)
    pivot: np.ndarray = field(default_factory=lambda: np.zeros(3))           # P from the reference point (m)

    @classmethod
    def of(cls, item) -> "Motion | Path | None":
        """The motion of a scene item with velocity, amplitude, frequency and phase keys (and
        angular_velocity, angular_amplitude, pivot), or a path (a plane, an obstacle); None if it
        does not move."""
        if getattr(item, "path", ()):
            return Path.of(item.path)
        velocity, amplitude = _vector(item.velocity), _vector(item.amplitude)
        spin = np.radians(_vector(getattr(item, "angular_velocity", ())))
        spin_amplitude = np.radians(_vector(getattr(item, "angular_amplitude", ())))
        oscillates = item.frequency > 0.0
        if not (velocity.any() or spin.any() or (oscillates and (amplitude.any() or spin_amplitude.any()))):
            return None
        return cls(velocity, amplitude, 2.0 * math.pi * item.frequency, math.radians(item.phase), spin,
                   spin_amplitude, _vector(getattr(item, "pivot", ())))

    @property
    def rotates(self) -> bool:
        return bool(self.spin.any() or self.spin_amplitude.any())

    def _axis(self) -> np.ndarray:
        w = self.spin if self.spin.any() else self.spin_amplitude
        return w / np.linalg.norm(w)

    def rotation(self, t: float) -> np.ndarray:
        """R(t): the rotation by theta(t) . e about the axis e (Rodrigues)."""
        if not self.rotates:
            return np.eye(3)
        e = self._axis()
        theta = self.spin * t + self.spin_amplitude * (math.sin(self.omega * t + self.phase) - math.sin(self.phase))
        angle = float(theta @ e)
        K = np.array([[0.0, -e[2], e[1]], [e[2], 0.0, -e[0]], [-e[1], e[0], 0.0]])
        return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)

    def angular_velocity(self, t: float) -> np.ndarray:
        """Omega(t) (rad/s)."""
        return self.spin + self.spin_amplitude * (self.omega * math.cos(self.omega * t + self.phase))

    def angular_acceleration(self, t: float) -> np.ndarray:
        """alpha(t) (rad/s^2)."""
        return self.spin_amplitude * (-self.omega ** 2 * math.sin(self.omega * t + self.phase))

    def displacement(self, t: float) -> np.ndarray:
        """X(t) (m)."""
        return self.velocity * t + self.amplitude * (math.sin(self.omega * t + self.phase) - math.sin(self.phase))

    def wall_velocity(self, t: float) -> np.ndarray:
        """u_w(t) (m/s)."""
        return self.velocity + self.amplitude * (self.omega * math.cos(self.omega * t + self.phase))

    def wall_acceleration(self, t: float) -> np.ndarray:
        """a_w(t) (m/s^2)."""
        return self.amplitude * (-self.omega ** 2 * math.sin(self.omega * t + self.phase))

    def largest_speed(self, reach: float = 0.0) -> float:
        """An upper bound of |u(r)| (m/s) over the wall's points within ``reach`` (m) of its pivot:
        the scene refuses walls as fast as sound."""
        translation = math.hypot(*self.velocity) + math.hypot(*self.amplitude) * self.omega  # hypot: no overflow
        return translation + (math.hypot(*self.spin) + math.hypot(*self.spin_amplitude) * self.omega) * reach


@dataclass(frozen=True)
class Path(_NoRotation):
    """A wall's tabulated translation (module docstring): times t (k,) s increasing, displacements X
    (k, 3) m, and the interpolant's slopes m (k, 3) m/s at the rows."""
    t: np.ndarray
    X: np.ndarray
    m: np.ndarray

    @classmethod
    def of(cls, rows) -> "Path":
        """From the scene's rows [t, x, y(, z)] (checked by the scene: increasing t, X_0 = 0)."""
        table = np.asarray(rows, dtype=np.float64)
        t = table[:, 0].copy()
        X = np.zeros((len(t), 3))
        X[:, : table.shape[1] - 1] = table[:, 1:]
        return cls(t, X, _monotone_slopes(t, X))

    def _segment(self, t: float):
        """(k, h, s) of the row interval holding t (s in [0, 1]), or None outside the table."""
        if not self.t[0] < t < self.t[-1]:
            return None
        k = min(int(np.searchsorted(self.t, t, side="right")) - 1, len(self.t) - 2)
        h = self.t[k + 1] - self.t[k]
        return k, h, (t - self.t[k]) / h

    def displacement(self, t: float) -> np.ndarray:
        seg = self._segment(t)
        if seg is None:
            return (self.X[0] if t <= self.t[0] else self.X[-1]).copy()
        k, h, s = seg
        s2, s3 = s * s, s * s * s
        return ((2 * s3 - 3 * s2 + 1) * self.X[k] + (s3 - 2 * s2 + s) * h * self.m[k]
                + (-2 * s3 + 3 * s2) * self.X[k + 1] + (s3 - s2) * h * self.m[k + 1])

    def wall_velocity(self, t: float) -> np.ndarray:
        seg = self._segment(t)
        if seg is None:
            return np.zeros(3)
        k, h, s = seg
        s2 = s * s
        return ((6 * s2 - 6 * s) * self.X[k] / h + (3 * s2 - 4 * s + 1) * self.m[k]
                + (-6 * s2 + 6 * s) * self.X[k + 1] / h + (3 * s2 - 2 * s) * self.m[k + 1])

    def wall_acceleration(self, t: float) -> np.ndarray:
        seg = self._segment(t)
        if seg is None:
            return np.zeros(3)
        k, h, s = seg
        return ((12 * s - 6) * self.X[k] / h ** 2 + (6 * s - 4) * self.m[k] / h
                + (-12 * s + 6) * self.X[k + 1] / h ** 2 + (6 * s - 2) * self.m[k + 1] / h)

    def largest_speed(self, reach: float = 0.0) -> float:
        """An upper bound of |u_w(t)| (m/s): on each interval each axis's speed is a quadratic in s,
        whose largest magnitude is at an end or at its vertex; the axes' largest, combined."""
        # a table of huge positions overflows to inf or NaN here: the caller refuses a bound that is
        # not finite, naming the key, so numpy's own warnings would only repeat it
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            h = np.diff(self.t)[:, None]
            d = np.diff(self.X, axis=0)
            m0, m1 = self.m[:-1], self.m[1:]
            # u(s) = a s^2 + b s + c on each interval (per axis), the derivative of the Hermite cubic
            a = 3 * (m0 + m1) - 6 * d / h
            b = 6 * d / h - 4 * m0 - 2 * m1
            c = m0
            ends = np.maximum(np.abs(c), np.abs(a + b + c))
            sv = np.where(a != 0, -b / (2 * a), -1.0)
            inside = (sv > 0) & (sv < 1)
            vertex = np.where(inside, np.abs(a * sv * sv + b * sv + c), 0.0)
            per_axis = np.maximum(ends, vertex).max(axis=0)
        return float(math.hypot(*per_axis))


def _monotone_slopes(t: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Fritsch-Carlson slopes (k, 3) at the rows: 0 at the ends and where the table turns, else the
    weighted harmonic mean of the neighbouring secants (which keeps each interval monotone)."""
    with np.errstate(over="ignore", invalid="ignore"):  # huge tables: largest_speed's bound says so
        h = np.diff(t)[:, None]
        delta = np.diff(X, axis=0) / h
    m = np.zeros_like(X)
    if len(t) > 2:
        d0, d1 = delta[:-1], delta[1:]
        h0, h1 = h[:-1], h[1:]
        w1, w2 = 2 * h1 + h0, h1 + 2 * h0
        same = np.sign(d0) * np.sign(d1) > 0  # (d0 * d1 overflowed for a path of 1e300 m: a warning on stderr)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            mean = (w1 + w2) / (w1 / d0 + w2 / d1)
        m[1:-1] = np.where(same, mean, 0.0)
    return m


def matmul3(A, B) -> np.ndarray:
    """A @ B of 3 x 3 matrices in plain float64 arithmetic, in a fixed order: every peer on every
    machine gets the same bits (a BLAS may fuse or reorder the products by the CPU it finds)."""
    a, b = A.tolist(), B.tolist()
    return np.array([[a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j] for j in range(3)] for i in range(3)])


def matvec3(A, x) -> np.ndarray:
    """A @ x (3 x 3 by 3) as ``matmul3``."""
    a, v = A.tolist(), x.tolist()
    return np.array([a[i][0] * v[0] + a[i][1] * v[1] + a[i][2] * v[2] for i in range(3)])


def _cross(u, v) -> np.ndarray:
    return np.array([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]])


def turn(phi) -> np.ndarray:
    """The rotation by the vector ``phi`` (rad): by |phi| about phi / |phi| (Rodrigues), in plain
    float64 arithmetic (``matmul3``)."""
    px, py, pz = (float(c) for c in phi)
    angle = math.sqrt(px * px + py * py + pz * pz)
    if angle == 0.0:
        return np.eye(3)
    ex, ey, ez = px / angle, py / angle, pz / angle
    s, c = math.sin(angle), 1.0 - math.cos(angle)
    # I + sin K + (1 - cos) K^2, K the cross-product matrix of e; K^2 = e e^T - I
    return np.array([[1.0 + c * (ex * ex - 1.0), -s * ez + c * ex * ey, s * ey + c * ex * ez],
                     [s * ez + c * ey * ex, 1.0 + c * (ey * ey - 1.0), -s * ex + c * ey * ez],
                     [-s * ey + c * ez * ex, s * ex + c * ez * ey, 1.0 + c * (ez * ez - 1.0)]])


def _solve(A, b) -> list:
    """x with A x = b, A symmetric positive definite (n <= 3, lists), by Gaussian elimination in a
    fixed order (no pivoting is needed for such an A)."""
    n = len(b)
    A = [row[:] for row in A]
    b = list(b)
    for k in range(n):
        for r in range(k + 1, n):
            f = A[r][k] / A[k][k]
            for j in range(k, n):
                A[r][j] -= f * A[k][j]
            b[r] -= f * b[k]
    x = [0.0] * n
    for k in reversed(range(n)):
        x[k] = (b[k] - sum(A[k][j] * x[j] for j in range(k + 1, n))) / A[k][k]
    return x


def inertia_tensor(shape: str, dim: int, mass: float, size=(0.0, 0.0, 0.0), radius: float = 0.0) -> np.ndarray:
    """The inertia tensor (3, 3) about the centre of a uniform box of edges ``size`` or a sphere of
    ``radius`` in its own axes (kg m^2; kg m per metre of depth in 2D, where a sphere is a disc, a
    cylinder along z, and a box a prism along z: only I_zz counts there)."""
    if shape == "sphere":
        k = (0.5 if dim == 2 else 0.4) * mass * radius * radius
        return np.diag([k, k, k])
    a, b, c = (float(s) for s in size[:3]) if dim == 3 else (float(size[0]), float(size[1]), 0.0)
    return mass / 12.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])


@dataclass
class FloatingBody(_NoRotation):
    """A rigid obstacle moved by the fluid (two-way coupling): its wall row ``wall``, mass M (kg; kg/m
    in 2D), the axes it may move along (``free``, 1 or 0) and, if it turns, the axes it may turn
    about (``free_rotation``: world axes through its centre). Each step the fluid's force and torque
    on it are (with sph.body_force = "traction" instead the surface integral of the fluid's traction
    at the points ``surface``, physics/traction.py) the reaction to the wall terms its wall exerts on
    the particles,

        F = - sum_i f_i,    T = sum_i (x_i - c) x (-f_i),    f_i = m_i (a_i^pressure + a_i^viscous)

    (that wall's share of physics/walls.py; c the body's centre, x_i the particle: a pressure force
    along the wall's normal has the same moment about c from x_i as from the wall point behind it),
    summed exactly (integers of ``quantum`` newtons, ``quantum`` x ``reach`` newton metres) over all
    peers. Then, by symplectic Euler like the fluid,

        a = free (F / M + b),   u += dt a,   X += dt u,

    b the body force of the fluid (gravity and forces.external, ramped alike; with forces.hydrostatic =
    "removed" the fluid feels no gravity and b adds the body's weight less its buoyancy,
    (1 - rho0 / rho_body) g: model.Model.body_acceleration), and, for a body that
    turns, Euler's equations in the world's axes with the body's inertia I = R I_0 R^T,

        I alpha = T - Omega x (I Omega)   on the free axes (alpha = 0 on the others),
        Omega += dt alpha,   R = turn(dt Omega) R,

    R its orientation since the scene placed it (the wall's geometry is turned by R about c, and its
    points move at u + Omega x (r - c): sphcore/boundaries.py Walls.at, physics/walls.py). On locked
    axes the joint takes the torque, so ``_solve`` runs on the free rows and columns of I only. All of
    it is float64 arithmetic in a fixed order (``matmul3``), so every peer moves the body to the same
    bits. X, u, a (and R, Omega, alpha) are state: checkpoints carry them (sphcore/checkpoint.py
    "bodies"). The coupling is explicit (the force of step n moves the body for step n + 1), which is
    stable for bodies not much lighter than the fluid they displace (added mass and inertia)."""
    wall: int
    mass: float
    free: np.ndarray                                          # (3,) 1.0 where the body may move
    free_rotation: np.ndarray = field(default_factory=lambda: np.zeros(3))  # (3,) 1.0 about the axes it may turn
    inertia: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))   # I_0: as the scene places it (kg m^2)
    reach: float = 1.0                                        # the farthest point from its centre (m): T's unit
    density: float = 0.0                                      # M / volume (kg/m^3): forces.hydrostatic = "removed"
    x: np.ndarray = field(default_factory=lambda: np.zeros(3))  # X (m) from the scene's position
    v: np.ndarray = field(default_factory=lambda: np.zeros(3))  # u (m/s)
    a: np.ndarray = field(default_factory=lambda: np.zeros(3))  # a (m/s^2)
    R: np.ndarray = field(default_factory=lambda: np.eye(3))    # orientation since the scene placed it
    w: np.ndarray = field(default_factory=lambda: np.zeros(3))  # Omega (rad/s)
    alpha: np.ndarray = field(default_factory=lambda: np.zeros(3))  # alpha (rad/s^2)
    force: np.ndarray = field(default_factory=lambda: np.zeros(3))  # the fluid's last force on it (N; N/m in 2D)
    torque: np.ndarray = field(default_factory=lambda: np.zeros(3))  # ... and torque about its centre (N m; N)
    surface: tuple = ()  # sph.body_force = "traction": (points, normals, areas) as placed (physics/traction.py)

    @property
    def surface_reach(self) -> float:
        """The farthest surface point from the centre (m): rows beyond it + H add nothing to the traction."""
        return float(np.sqrt((self.surface[0] ** 2).sum(axis=1)).max())

    STATE = ("x", "v", "a", "R", "w", "alpha", "force", "torque")  # where it is and how it moves (solver._same)

    @property
    def rotates(self) -> bool:
        return bool(self.free_rotation.any())

    def displacement(self, t: float) -> np.ndarray:
        return self.x

    def wall_velocity(self, t: float) -> np.ndarray:
        return self.v

    def wall_acceleration(self, t: float) -> np.ndarray:
        return self.a

    def rotation(self, t: float) -> np.ndarray:
        return self.R

    def angular_velocity(self, t: float) -> np.ndarray:
        return self.w

    def angular_acceleration(self, t: float) -> np.ndarray:
        return self.alpha

    def quantum(self, gravity) -> float:
        """The unit of the exact force sum (N): 2^-40 of the body's weight (or of M x 1 m/s^2)."""
        return self.mass * max(float(np.linalg.norm(gravity)), 1.0) * 2.0 ** -40

    def advance(self, force, body_acceleration, dt: float, torque=(0.0, 0.0, 0.0)):
        """One step under the fluid's ``force`` and ``torque`` and the body force (class docstring)."""
        self.force = np.asarray(force, dtype=np.float64)
        self.a = self.free * (self.force / self.mass + np.asarray(body_acceleration, dtype=np.float64))
        self.v = self.v + dt * self.a
        self.x = self.x + dt * self.v
        if not self.rotates:
            return
        self.torque = np.asarray(torque, dtype=np.float64)
        inertia = matmul3(matmul3(self.R, self.inertia), self.R.T)
        rhs = self.torque - _cross(self.w, matvec3(inertia, self.w))  # T - Omega x (I Omega)
        axes = [k for k in range(3) if self.free_rotation[k]]
        alpha = np.zeros(3)
        alpha[axes] = _solve([[inertia[r, c] for c in axes] for r in axes], [rhs[r] for r in axes])
        self.alpha = alpha
        self.w = self.w + dt * self.alpha
        self.R = matmul3(turn(dt * self.w), self.R)

    def state(self) -> list:
        """X, u, a as 9 floats (a checkpoint's "bodies" entry), then R, Omega, alpha (15 more) for a
        body that turns."""
        parts = (self.x, self.v, self.a) + ((self.R.ravel(), self.w, self.alpha) if self.rotates else ())
        return [float(c) for part in parts for c in part]

    def set_state(self, values):
        """From ``state()``'s list; ValueError if it is not this body's (its length, or an R that is
        not a rotation)."""
        values = np.asarray(values, dtype=np.float64)
        if values.shape != (24 if self.rotates else 9,):
            raise ValueError(f"expected {24 if self.rotates else 9} numbers for a body that "
                             f"{'turns' if self.rotates else 'does not turn'}, got {values.size}")
        if self.rotates:
            R = values[9:18].reshape(3, 3)
            if not (np.allclose(R @ R.T, np.eye(3), atol=1e-9) and np.linalg.det(R) > 0.0):
                raise ValueError("its orientation (numbers 10-18) is not a rotation matrix")
            self.R, self.w, self.alpha = R.copy(), values[18:21].copy(), values[21:24].copy()
        self.x, self.v, self.a = values[0:3].copy(), values[3:6].copy(), values[6:9].copy()
