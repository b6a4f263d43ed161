"""The end of a step for one particle: the statistics that choose dt (and catch NaN), the time
integrator (symplectic Euler, leapfrog kick-drift-kick: Leimkuhler & Reich 2004, ch. 4) and the
boundaries: periodic wrapping and the wall collision guard (walls.py)."""
import math

from numba import njit

from sphcore.physics.walls import signed_distance, wall_point_velocity
from sphcore.physics.real import like


@njit(cache=True, inline="always")
def integrate_row(integrator, use_drift, i, x, v, a, dv, dt, dt_prev):
    """Symplectic Euler: v += dt a; x += dt v.  Leapfrog KDK with staggered velocities:
    v_{n+1/2} = v_{n-1/2} + (dt_prev + dt)/2 a_n; x += dt v_{n+1/2}. XSPH adds dv to the drift."""
    if integrator == 0:
        kick = dt
    else:
        kick = like(dt, 0.5) * (dt_prev + dt)
    for c in range(3):
        v[i, c] += kick * a[i, c]
        if use_drift:
            x[i, c] += dt * (v[i, c] + dv[i, c])
        else:
            x[i, c] += dt * v[i, c]


@njit(cache=True, inline="always")
def wrap(x, lo, L):
    """Map x into [lo, lo + L) on a periodic axis (L > 0); unchanged if L == 0."""
    if L > 0.0:
        s = x - lo
        s -= L * math.floor(s / L)
        if s >= L:  # round-off of the floor above
            s = like(L, 0.0)
        return lo + s
    return x


@njit(cache=True, inline="always")
def _reflect(v, i, c, vn, nc, u, prm):
    """Velocity component c after a wall contact, relative to the wall (moving at u along c): the
    tangential part damped by friction, the normal part vn reversed with restitution."""
    vt = v[i, c] - u - vn * nc
    v[i, c] = u + vt * (like(vt, 1.0) - prm.friction) - prm.restitution * vn * nc


@njit(cache=True, inline="always")
def boundaries_row(periodic, prm, i, x, v, lo, wall_kind, wall_data, wall_motion):
    """Wrap periodic axes; push a particle closer than wall_gap back out with restitution/friction
    (relative to the wall's velocity, motion.py); returns 1 if it was found behind a wall (d < 0: a
    leak), else 0.   (walls.py)"""
    if periodic:
        x[i, 0] = wrap(x[i, 0], lo[0], prm.period_x)
        x[i, 1] = wrap(x[i, 1], lo[1], prm.period_y)
        x[i, 2] = wrap(x[i, 2], lo[2], prm.period_z)
    hit = 0
    for sweep in range(2):  # a second sweep settles corners where two walls push in turn
        for q in range(wall_kind.shape[0]):
            d, nx, ny, nz = signed_distance(wall_kind[q], wall_data[q], x[i, 0], x[i, 1], x[i, 2])
            if d < 0.0 and sweep == 0:
                hit = 1
            if d < prm.wall_gap:
                push = prm.wall_gap - d
                x[i, 0] += push * nx
                x[i, 1] += push * ny
                x[i, 2] += push * nz
                # the wall's velocity at its point nearest the particle (before the push)
                ux, uy, uz = wall_point_velocity(wall_motion, q, x[i, 0] - prm.wall_gap * nx,
                                                 x[i, 1] - prm.wall_gap * ny, x[i, 2] - prm.wall_gap * nz)
                vn = (v[i, 0] - ux) * nx + (v[i, 1] - uy) * ny + (v[i, 2] - uz) * nz
                if vn < 0.0:
                    _reflect(v, i, 0, vn, nx, ux, prm)
                    _reflect(v, i, 1, vn, ny, uy, prm)
                    _reflect(v, i, 2, vn, nz, uz, prm)
    return hit


@njit(cache=True, inline="always")
def statistics_row(i, x, v, a, rho, rho0):
    """(|v_i|^2, |a_i|^2, rho_i/rho0 - 1, bad) of row i; the step takes the maxima of the first three
    and the sum of ``bad``: 1 if row i holds NaN or Inf (then the others are 0), else 0."""
    v2 = v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1] + v[i, 2] * v[i, 2]
    a2 = a[i, 0] * a[i, 0] + a[i, 1] * a[i, 1] + a[i, 2] * a[i, 2]
    r = rho[i] / rho0 - 1.0  # float64, as the reduction that takes the maxima (stages.REDUCTIONS "max")
    if math.isfinite(v2 + a2 + r + x[i, 0] + x[i, 1] + x[i, 2]):
        return v2, a2, r, 0
    zero = like(rho0, 0.0)  # rho0 is finite and of the run's precision, like v2, a2 and r
    return zero, zero, zero, 1
