"""Turbulent wall friction: a wall function for walls whose boundary layer the particles cannot
resolve (``terms.wall_friction = nu``, the fluid's kinematic viscosity in m^2/s).

A free-slip wall exerts no shear, and a no-slip wall (the Morris viscosity's, walls.py) shears the
fluid only through the velocity difference across one spacing, so at a Reynolds number of 1e4-1e5
(a dam break's surge over a smooth floor) both leave out the turbulent boundary layer's wall stress,
tau_w = rho u_tau^2, which is ten times what a laminar gradient over a spacing gives there. The
classical remedy of finite-volume codes is a wall function (Launder & Spalding 1974, "The numerical
computation of turbulent flows", Comput. Methods Appl. Mech. Eng. 3, 269): the first point's
tangential speed U at its wall distance y sets u_tau through the law of the wall. Here the law is
Spalding's (1961, "A single formula for the law of the wall", J. Appl. Mech. 28, 455), one formula
through the viscous sublayer, the buffer layer and the log layer, so no y+ switch is needed:

    y+ = u+ + e^{-kappa B} (e^{kappa u+} - 1 - kappa u+ - (kappa u+)^2 / 2 - (kappa u+)^3 / 6),
    u+ = U / u_tau,   y+ = y u_tau / nu,   kappa = 0.41,  B = 5.2 (a smooth wall)

SPH codes apply such a stress through the particles near the wall (Violeau & Issa 2007, "Numerical
modelling of complex turbulent free-surface flows with the SPH method: an overview", Int. J. Numer.
Meth. Fluids 53, 277; Ferrand et al. 2013, the semi-analytical walls' wall function). With the
analytic walls of walls.py there is no wall particle to carry it, so the stress is spread over the
fluid particles near the wall by the weight omega(d) (``boundaries.wall_tables``, row 5): the
kernel's lateral sum at distance d, normalised so that the particles of a lattice column next to the
wall (mass rho0 / S each) take exactly the stress of their wall area dx^(dim-1); with a support of
2.3 spacings 94 % of it falls on the first row. Per particle, relative to the wall's velocity u_w at
its nearest point:

    a_i += - u_tau^2(U_i, y_i) omega(d_i) t_i,   U_i t_i = (v_i - u_w) - ((v_i - u_w) . n) n

so a lattice column's particles (mass m = rho0 / S each, sum_k omega(d_k) = S dx^(dim-1)) feel
sum_k m a_k = -rho0 u_tau^2 dx^(dim-1) t: the wall stress tau_w = rho0 u_tau^2 on their wall area.
y_i = max(d_i, dx / 2): a particle is a layer of fluid one spacing thick, and one pressed closer than
the first lattice row still stands for that layer.

A floating body's wall takes the reaction: physics/bodies.py adds -m_i times this term of the body's
wall alone to the fluid's force on it, so the pair conserves momentum.

Stability: the term is a drag -k (v_i - u_w) with k = u_tau^2 omega / U; explicit, it must not
reverse the slip within a step, so k is capped at 1 / dt_prev (the previous step; the step's own dt
is chosen after the forces). At the validation cases' values k dt is ~1e-4, far below the cap.

u+ solves g(u+) = u+ y+(u+) - R = 0, R = y U / nu (g increases and is convex) by Newton from the
upper bound min(sqrt R, ln R / kappa + B + 1), a fixed number of times, so that every backend and
every peer takes the same steps.
"""
import math

from numba import njit

from sphcore.physics.real import like
from sphcore.physics.walls import signed_distance, table_lookup, wall_point_velocity

KAPPA = 0.41      # von Karman's constant
B_SMOOTH = 5.2    # the log law's intercept over a smooth wall
NEWTON_STEPS = 12  # from the upper bound; converged to round-off by 6-8 for 1e-3 < R < 1e8
OMEGA_ROW = 5     # the stress-share table's row in boundaries.wall_tables
E_KB = math.exp(-KAPPA * B_SMOOTH)  # e^{-kappa B}, here so that a float32 kernel does not compute it in float64
LOG_BOUND = B_SMOOTH + 1.0          # u+ <= ln R / kappa + B + 1 (the Newton start)


@njit(cache=True, inline="always")
def spalding_u_plus(R):
    """u+ of Spalding's law for R = y U / nu = u+ y+ (module docstring); 0 for R <= 0."""
    if R <= 0.0:
        return like(R, 0.0)
    kappa = like(R, KAPPA)
    e_kb = like(R, E_KB)
    one = like(R, 1.0)
    u = min(math.sqrt(R), math.log(max(R, one)) / kappa + like(R, LOG_BOUND))
    for _ in range(NEWTON_STEPS):
        k = kappa * u
        ek = math.exp(k)
        y_plus = u + e_kb * (ek - one - k - like(R, 0.5) * k * k - k * k * k / like(R, 6.0))
        dy_plus = one + e_kb * kappa * (ek - one - k - like(R, 0.5) * k * k)
        u -= (u * y_plus - R) / (y_plus + u * dy_plus)
    return u


@njit(cache=True, inline="always")
def wall_friction_acceleration(prm, kinds, data, tables, motion, x, y, z, vx, vy, vz, dt_prev):
    """(ax, ay, az) = -sum over the walls q within reach of u_tau^2 omega(d_q) t_q at (x, y, z) moving
    at (vx, vy, vz), nu = prm.wall_nu (module docstring); a floating body's reaction sums it over its
    own wall alone."""
    nu = prm.wall_nu
    ax = like(nu, 0.0)
    ay = like(nu, 0.0)
    az = like(nu, 0.0)
    for q in range(kinds.shape[0]):
        d, nx, ny, nz = signed_distance(kinds[q], data[q], x, y, z)
        if d >= prm.wall_table_end:
            continue
        omega = table_lookup(tables[OMEGA_ROW], d, prm.wall_table_end)
        uwx, uwy, uwz = wall_point_velocity(motion, q, x - d * nx, y - d * ny, z - d * nz)
        sx, sy, sz = vx - uwx, vy - uwy, vz - uwz
        sn = sx * nx + sy * ny + sz * nz
        sx -= sn * nx
        sy -= sn * ny
        sz -= sn * nz
        U = math.sqrt(sx * sx + sy * sy + sz * sz)
        if U == 0.0 or omega <= 0.0:
            continue
        yw = max(d, like(d, 0.5) * prm.dx)
        u_tau = U / spalding_u_plus(yw * U / nu)
        k = u_tau * u_tau * omega / U   # the drag rate (1/s) on the slip
        if dt_prev > 0.0:
            k = min(k, like(k, 1.0) / dt_prev)
        ax -= k * sx
        ay -= k * sy
        az -= k * sz
    return ax, ay, az


@njit(cache=True, inline="always")
def wall_friction_row(prm, i, x, v, wall_kind, wall_data, wall_tables, wall_motion, dt_prev, a):
    """a_i += -u_tau^2 omega(d) t per wall within reach (nu = prm.wall_nu, terms.wall_friction).   (wall_friction.py)"""
    ax, ay, az = wall_friction_acceleration(prm, wall_kind, wall_data, wall_tables, wall_motion, x[i, 0], x[i, 1],
                                            x[i, 2], v[i, 0], v[i, 1], v[i, 2], dt_prev)
    a[i, 0] += ax
    a[i, 1] += ay
    a[i, 2] += az
