"""The work of one row (one particle) in every stage: the physics written once for both backends.

Each ``*_row`` function computes and writes row ``i`` only, reading its neighbours through the
neighbour list (gather, never scatter). The CPU drivers (``backends/cpu.py``) call them inside
``prange`` loops; the CUDA kernels (``backends/cuda.py``) call them with one thread per row. They are
``@njit(inline="always")``, so each driver or kernel compiles them inline with its own compile-time
choices (kernel family, EOS, viscosity model, integrator, periodicity): the branches a scene does not
use are pruned on both targets.

Rules that keep them compilable for CUDA: scalars and arrays only (no allocation, no exceptions,
no Python objects), loops over integers, and typed zeros spelled ``0.0 * prm.H`` so float32 runs stay
float32.
"""
import math

from numba import njit

from sphcore.grid import minimum_image
from sphcore.physics.density import density_pair
from sphcore.physics.continuity import density_rate_pair, diffusion_pair, hydrostatic_difference
from sphcore.physics.dfsph import increment, inverse_diagonal, source
from sphcore.physics.eos import pressure, sound_speed_sq
from sphcore.physics.external import body_acceleration, central_acceleration
from sphcore.physics.kernels import dw_dr_over_r, lap_w_viscosity, w
from sphcore.physics.pressure import pressure_pair
from sphcore.physics.surface_tension import colour_gradient_pair, colour_laplacian_pair, surface_tension_factor
from sphcore.physics.viscosity import artificial_pair, morris_pair, muller_pair
from sphcore.physics.vorticity import confinement, curl_pair
from sphcore.physics.walls import fill_fraction, signed_distance, wall_terms, wall_viscosity
from sphcore.physics.shifting import SURFACE_CONCENTRATION, concentration_gradient_pair
from sphcore.physics.xsph import xsph_pair


@njit(cache=True, inline="always")
def separation(periodic, x, i, j, prm):
    """x_ij = x_i - x_j with the minimum-image convention on periodic axes (grid.minimum_image)."""
    dx = x[i, 0] - x[j, 0]
    dy = x[i, 1] - x[j, 1]
    dz = x[i, 2] - x[j, 2]
    if periodic:
        if prm.period_x > 0.0:
            dx = minimum_image(dx, prm.period_x)
        if prm.period_y > 0.0:
            dy = minimum_image(dy, prm.period_y)
        if prm.period_z > 0.0:
            dz = minimum_image(dz, prm.period_z)
    return dx, dy, dz


@njit(cache=True, inline="always")
def wall_density_gradient(kernel, prm, wall_kind, wall_data, wall_tables, x, i, rho_i, theta):
    """g_i^wall = grad_i of the wall's density share theta rho0 Phi(d_i): the walls' pressure push at
    p_i = rho_i^2 / 2 without body force is -sum_virtual m grad W = -g_i^wall / theta.   (walls.py)"""
    _, fx, fy, fz = wall_terms(kernel, prm, True, wall_kind, wall_data, wall_tables, x[i, 0], x[i, 1], x[i, 2],
                               0.5 * rho_i * rho_i, rho_i, 0.0 * rho_i, 0.0 * rho_i, 0.0 * rho_i)
    return -theta * fx, -theta * fy, -theta * fz


@njit(cache=True, inline="always")
def density_row(kernel, eos, periodic, continuity, prm, i, x, v, m, nbr, counts, wall_kind, wall_data, wall_tables,
                dt_prev, commit, rho_c, rho, p, fill):
    """rho_i = m_i W(0) + sum_j m_j W_ij + theta_i rho0 Phi(d_i);  p_i = EOS(rho_i); fill_i = theta_i.
    With ``continuity``: rho_i = rho_c[i] + dt_prev D rho_i/Dt, the carried density advanced by the
    continuity equation over the previous step with the velocities that moved the particles here
    (stored back if ``commit``; a carried 0 starts at rho0). (density.py, continuity.py, eos.py, walls.py)"""
    rho_i = m[i] * prm.w0
    rate = 0.0 * rho_i
    for k in range(counts[i]):
        j = nbr[i, k]
        dx, dy, dz = separation(periodic, x, i, j, prm)
        r2 = dx * dx + dy * dy + dz * dz
        r_ij = math.sqrt(r2)
        rho_i += density_pair(kernel, m[j], r_ij, prm.H, prm.s_w)
        if continuity and r2 > 0.0:
            g = dw_dr_over_r(kernel, r_ij, prm.H, prm.s_g)
            rate += density_rate_pair(m[j], v[i, 0] - v[j, 0], v[i, 1] - v[j, 1], v[i, 2] - v[j, 2],
                                      g * dx, g * dy, g * dz)
    drho, _, _, _ = wall_terms(kernel, prm, False, wall_kind, wall_data, wall_tables, x[i, 0], x[i, 1], x[i, 2],
                               0.0 * rho_i, rho_i, 0.0 * rho_i, 0.0 * rho_i, 0.0 * rho_i)
    theta = fill_fraction(rho_i, drho, prm.rho0)
    fill[i] = theta
    rho_i += theta * drho
    if continuity:
        if rho_c[i] <= 0.0:  # a new run: its lattice is at rest density (continuity.py)
            rho_c[i] = prm.rho0
            rho_i = rho_c[i]
        else:
            # the wall's share theta rho0 Phi(d) changes at its gradient . v_i
            r = rho_c[i]
            wx, wy, wz = wall_density_gradient(kernel, prm, wall_kind, wall_data, wall_tables, x, i, r, theta)
            rate += wx * v[i, 0] + wy * v[i, 1] + wz * v[i, 2]
            rho_i = r + dt_prev * rate
            if commit:
                rho_c[i] = rho_i
    rho[i] = rho_i
    p[i] = pressure(eos, rho_i, prm.rho0, prm.c0, prm.clamp_negative)


@njit(cache=True, inline="always")
def diffusion_row(kernel, eos, periodic, prm, i, x, m, rho, nbr, counts, drho):
    """drho_i = the delta-SPH density diffusion with its hydrostatic correction.   (continuity.py)"""
    rho_i = rho[i]
    diff = 0.0 * rho_i
    for k in range(counts[i]):
        j = nbr[i, k]
        dx, dy, dz = separation(periodic, x, i, j, prm)
        r2 = dx * dx + dy * dy + dz * dz
        if r2 == 0.0:
            continue
        g = dw_dr_over_r(kernel, math.sqrt(r2), prm.H, prm.s_g)
        # (dx, dy, dz) = x_i - x_j; the pair's mean density sets the hydrostatic step (symmetric in i, j)
        rho_m = 0.5 * (rho_i + rho[j])
        hydro = hydrostatic_difference(rho_m, sound_speed_sq(eos, rho_m, prm.rho0, prm.c0),
                                       prm.gravity_x, prm.gravity_y, prm.gravity_z, -dx, -dy, -dz)
        diff += diffusion_pair(m[j], rho_i, rho[j], hydro, g)
    drho[i] = prm.delta_hc0 * diff


@njit(cache=True, inline="always")
def density_update_row(i, rho_c, drho, dt):
    """rho_i += dt drho_i (the carried density; continuity.py)."""
    rho_c[i] += dt * drho[i]


@njit(cache=True, inline="always")
def acceleration_row(kernel, viscosity, periodic, prm, i, x, v, m, rho, p, nbr, counts, wall_kind, wall_data,
                     wall_tables, fill, a):
    """a_i = pressure + viscosity + body force + wall pressure.   (pressure.py, viscosity.py,
    external.py, walls.py)"""
    bx, by, bz = body_acceleration(prm)
    if prm.central_omega2 > 0.0:
        cx, cy, cz = central_acceleration(prm, x[i, 0], x[i, 1], x[i, 2])
        bx += cx
        by += cy
        bz += cz
    ax = bx * 1.0
    ay = by * 1.0
    az = bz * 1.0
    rho_i = rho[i]
    p_i = p[i]
    p_rho2_i = p_i / (rho_i * rho_i)
    for k in range(counts[i]):
        j = nbr[i, k]
        dx, dy, dz = separation(periodic, x, i, j, prm)
        r2 = dx * dx + dy * dy + dz * dz
        if r2 == 0.0:
            continue  # coincident particles: no direction, no pressure force
        r_ij = math.sqrt(r2)
        dw_over_r = dw_dr_over_r(kernel, r_ij, prm.H, prm.s_g)
        f = pressure_pair(m[j], p_rho2_i, p[j], rho[j], dw_over_r)
        if viscosity == 1:  # Viscosity.ARTIFICIAL
            vdotx = ((v[i, 0] - v[j, 0]) * dx + (v[i, 1] - v[j, 1]) * dy + (v[i, 2] - v[j, 2]) * dz)
            f += artificial_pair(m[j], vdotx, r2, rho_i, rho[j], dw_over_r, prm.alpha, prm.c0, prm.h)
        ax += f * dx
        ay += f * dy
        az += f * dz
        if viscosity == 2:  # Viscosity.MULLER: along v_j - v_i
            g = muller_pair(m[j], rho_i, rho[j], lap_w_viscosity(r_ij, prm.H, prm.s_l), prm.mu)
            ax += g * (v[j, 0] - v[i, 0])
            ay += g * (v[j, 1] - v[i, 1])
            az += g * (v[j, 2] - v[i, 2])
        elif viscosity == 3:  # Viscosity.MORRIS: along v_i - v_j
            g = morris_pair(m[j], r2, rho_i, rho[j], dw_over_r, prm.mu, prm.h)
            ax += g * (v[i, 0] - v[j, 0])
            ay += g * (v[i, 1] - v[j, 1])
            az += g * (v[i, 2] - v[j, 2])
    _, wx, wy, wz = wall_terms(kernel, prm, True, wall_kind, wall_data, wall_tables, x[i, 0], x[i, 1], x[i, 2],
                               p_i, rho_i, bx, by, bz)
    ax += fill[i] * wx
    ay += fill[i] * wy
    az += fill[i] * wz
    if viscosity == 3:  # Viscosity.MORRIS: no-slip walls
        kv = fill[i] * wall_viscosity(prm, wall_kind, wall_data, wall_tables, x[i, 0], x[i, 1], x[i, 2], rho_i)
        ax += kv * v[i, 0]
        ay += kv * v[i, 1]
        az += kv * v[i, 2]
    a[i, 0] = ax
    a[i, 1] = ay
    a[i, 2] = az


@njit(cache=True, inline="always")
def dfsph_factor_row(kernel, periodic, prm, i, x, m, rho, nbr, counts, wall_kind, wall_data, wall_tables, fill, p,
                     wgrad, inv_d, lam_sum):
    """DFSPH set-up of row i at the step's positions: the wall gradient g_i^wall, 1 / D_i, and p_i = 0
    (the forces stage then gives the non-pressure accelerations).   (dfsph.py)"""
    gx = 0.0 * prm.H
    gy = 0.0 * prm.H
    gz = 0.0 * prm.H
    sum_sq = 0.0 * prm.H
    for k in range(counts[i]):
        j = nbr[i, k]
        dx, dy, dz = separation(periodic, x, i, j, prm)
        r2 = dx * dx + dy * dy + dz * dz
        if r2 == 0.0:
            continue
        g = m[j] * dw_dr_over_r(kernel, math.sqrt(r2), prm.H, prm.s_g)
        gx += g * dx
        gy += g * dy
        gz += g * dz
        sum_sq += g * g * r2
    rho_i = rho[i]
    wx, wy, wz = wall_density_gradient(kernel, prm, wall_kind, wall_data, wall_tables, x, i, rho_i, fill[i])
    wgrad[i, 0] = wx
    wgrad[i, 1] = wy
    wgrad[i, 2] = wz
    inv_d[i] = inverse_diagonal(gx, gy, gz, wx, wy, wz, sum_sq, prm.dfsph_d0)
    p[i] = 0.0 * rho_i
    lam_sum[i] = 0.0 * rho_i  # the divergence solve starts from zero


@njit(cache=True, inline="always")
def dfsph_source_row(kernel, periodic, divergence, prm, i, x, v, m, rho, nbr, counts, wgrad, inv_d, dt, share,
                     rho_ref, lam_sum, lam):
    """This iteration's lambda_i = s_i / D_i from the velocities v, projected so that the solve's sum
    stays >= 0 with free surfaces (dfsph.py); returns the density error it removes, |lambda_i| D_i / rho0
    (0 for a particle without neighbours: nothing to solve there)."""
    rate = wgrad[i, 0] * v[i, 0] + wgrad[i, 1] * v[i, 1] + wgrad[i, 2] * v[i, 2]
    for k in range(counts[i]):
        j = nbr[i, k]
        dx, dy, dz = separation(periodic, x, i, j, prm)
        r2 = dx * dx + dy * dy + dz * dz
        if r2 == 0.0:
            continue
        g = dw_dr_over_r(kernel, math.sqrt(r2), prm.H, prm.s_g)
        rate += density_rate_pair(m[j], v[i, 0] - v[j, 0], v[i, 1] - v[j, 1], v[i, 2] - v[j, 2],
                                  g * dx, g * dy, g * dz)
    s = source(divergence, rho[i], rho_ref, rate, dt, share)
    inv = inv_d[i]
    if counts[i] == 0:  # alone: no neighbour to push, nothing to solve
        lam[i] = 0.0 * s
        return 0.0 * s
    dl = increment(prm.clamp_negative, prm.dfsph_omega * s * inv, lam_sum[i])  # inv = 1 / max(D_i, d0)
    lam[i] = dl
    return abs(dl) / inv / prm.rho0


@njit(cache=True, inline="always")
def dfsph_update_row(kernel, periodic, prm, i, x, m, lam, nbr, counts, wgrad, inv_dt, v, lam_sum):
    """v_i -= (1/dt) [sum_j m_j (lambda_i + lambda_j) grad W_ij + lambda_i g_i^wall];
    lam_sum_i += lambda_i.   (dfsph.py)"""
    l_i = lam[i]
    sx = l_i * wgrad[i, 0]
    sy = l_i * wgrad[i, 1]
    sz = l_i * wgrad[i, 2]
    for k in range(counts[i]):
        j = nbr[i, k]
        dx, dy, dz = separation(periodic, x, i, j, prm)
        r2 = dx * dx + dy * dy + dz * dz
        if r2 == 0.0:
            continue
        g = m[j] * (l_i + lam[j]) * dw_dr_over_r(kernel, math.sqrt(r2), prm.H, prm.s_g)
        sx += g * dx
        sy += g * dy
        sz += g * dz
    v[i, 0] -= inv_dt * sx
    v[i, 1] -= inv_dt * sy
    v[i, 2] -= inv_dt * sz
    lam_sum[i] += l_i


@njit(cache=True, inline="always")
def dfsph_kick_row(i, v, a, dt, kappa, v_star, lam, lam_sum):
    """v*_i = v_i + dt a_i (non-pressure accelerations); the density solve's warm start is the
    previous step's pressure, lambda_i = kappa_i dt^2 (applied by one update before iterating)."""
    for c in range(3):
        v_star[i, c] = v[i, c] + dt * a[i, c]
    lam[i] = kappa[i] * dt * dt
    lam_sum[i] = 0.0 * dt


@njit(cache=True, inline="always")
def dfsph_finish_row(i, v, v_star, rho, lam_sum, inv_dt, store, a, p, kappa):
    """a_i = (v*_i - v_i) / dt, so that the integrator's kick lands on v*; if ``store``: kappa_i =
    sum lambda / dt^2 (the next step's warm start), p_i = rho_i^2 kappa_i. A step shortened to land on
    an output time does not store: its lambda also removes the velocity field's residual divergence,
    which does not shrink with dt, so sum lambda / dt^2 would be a meaningless, huge pressure."""
    for c in range(3):
        a[i, c] = (v_star[i, c] - v[i, c]) * inv_dt
    if store:
        k = lam_sum[i] * inv_dt * inv_dt
        kappa[i] = k
        p[i] = rho[i] * rho[i] * k


@njit(cache=True, inline="always")
def surface_tension_row(kernel, periodic, prm, i, x, m, rho, nbr, counts, a):
    """Colour-field surface tension, a_i += -sigma lap c_i n_i / (|n_i| rho_i).   (surface_tension.py)"""
    gx = 0.0 * prm.H
    gy = 0.0 * prm.H
    gz = 0.0 * prm.H
    lap_c = 0.0 * prm.H
    for k in range(counts[i]):
        j = nbr[i, k]
        dx, dy, dz = separation(periodic, x, i, j, prm)
        r2 = dx * dx + dy * dy + dz * dz
        if r2 == 0.0:
            continue
        r_ij = math.sqrt(r2)
        f = colour_gradient_pair(m[j], rho[j], dw_dr_over_r(kernel, r_ij, prm.H, prm.s_g))
        gx += f * dx
        gy += f * dy
        gz += f * dz
        lap_c += colour_laplacian_pair(m[j], rho[j], lap_w_viscosity(r_ij, prm.H, prm.s_l))
    norm = math.sqrt(gx * gx + gy * gy + gz * gz)
    s = surface_tension_factor(prm.sigma, lap_c, norm, rho[i], prm.st_threshold)
    a[i, 0] += s * gx
    a[i, 1] += s * gy
    a[i, 2] += s * gz


@njit(cache=True, inline="always")
def vorticity_row(kernel, periodic, prm, i, x, v, m, rho, nbr, counts, omega):
    """omega_i = sum_j m_j / rho_j grad W_ij x (v_j - v_i).   (vorticity.py)"""
    ox = 0.0 * prm.H
    oy = 0.0 * prm.H
    oz = 0.0 * prm.H
    for k in range(counts[i]):
        j = nbr[i, k]
        dx, dy, dz = separation(periodic, x, i, j, prm)
        r2 = dx * dx + dy * dy + dz * dz
        if r2 == 0.0:
            continue
        r_ij = math.sqrt(r2)
        g = dw_dr_over_r(kernel, r_ij, prm.H, prm.s_g)
        cx, cy, cz = curl_pair(m[j] / rho[j], v[j, 0] - v[i, 0], v[j, 1] - v[i, 1], v[j, 2] - v[i, 2],
                               g * dx, g * dy, g * dz)
        ox += cx
        oy += cy
        oz += cz
    omega[i, 0] = ox
    omega[i, 1] = oy
    omega[i, 2] = oz


@njit(cache=True, inline="always")
def confinement_row(kernel, periodic, prm, i, x, m, rho, omega, nbr, counts, a):
    """a_i += eps N_i x omega_i, N = eta/|eta|, eta_i = sum_j m_j/rho_j |omega_j| grad W_ij."""
    ex = 0.0 * prm.H
    ey = 0.0 * prm.H
    ez = 0.0 * prm.H
    for k in range(counts[i]):
        j = nbr[i, k]
        dx, dy, dz = separation(periodic, x, i, j, prm)
        r2 = dx * dx + dy * dy + dz * dz
        if r2 == 0.0:
            continue
        r_ij = math.sqrt(r2)
        wj = math.sqrt(omega[j, 0] ** 2 + omega[j, 1] ** 2 + omega[j, 2] ** 2)
        g = m[j] / rho[j] * wj * dw_dr_over_r(kernel, r_ij, prm.H, prm.s_g)
        ex += g * dx
        ey += g * dy
        ez += g * dz
    norm = math.sqrt(ex * ex + ey * ey + ez * ez)
    if norm > 0.0:
        fx, fy, fz = confinement(prm.vorticity_eps, ex / norm, ey / norm, ez / norm,
                                 omega[i, 0], omega[i, 1], omega[i, 2])
        a[i, 0] += fx
        a[i, 1] += fy
        a[i, 2] += fz


@njit(cache=True, inline="always")
def xsph_row(kernel, periodic, prm, i, x, v, m, rho, nbr, counts, dv):
    """dv_i = eps sum_j m_j / rho_ij (v_j - v_i) W_ij (the drift uses v + dv).   (xsph.py)"""
    sx = 0.0 * prm.H
    sy = 0.0 * prm.H
    sz = 0.0 * prm.H
    for k in range(counts[i]):
        j = nbr[i, k]
        dx, dy, dz = separation(periodic, x, i, j, prm)
        r_ij = math.sqrt(dx * dx + dy * dy + dz * dz)
        f = xsph_pair(m[j], rho[i], rho[j], w(kernel, r_ij, prm.H, prm.s_w))
        sx += f * (v[j, 0] - v[i, 0])
        sy += f * (v[j, 1] - v[i, 1])
        sz += f * (v[j, 2] - v[i, 2])
    dv[i, 0] = prm.xsph_eps * sx
    dv[i, 1] = prm.xsph_eps * sy
    dv[i, 2] = prm.xsph_eps * sz


@njit(cache=True, inline="always")
def shifting_row(kernel, periodic, prm, i, x, v, m, rho, nbr, counts, wall_kind, wall_data, add, dv):
    """Particle shifting as a drift velocity, -A h |v_i| grad C_i, free-surface and wall-normal
    components removed (shifting.py); added to dv if ``add`` (XSPH wrote it), else written."""
    gx = 0.0 * prm.H
    gy = 0.0 * prm.H
    gz = 0.0 * prm.H
    c = m[i] / prm.rho0 * prm.w0
    for k in range(counts[i]):
        j = nbr[i, k]
        dx, dy, dz = separation(periodic, x, i, j, prm)
        r2 = dx * dx + dy * dy + dz * dz
        r_ij = math.sqrt(r2)
        c += m[j] / prm.rho0 * w(kernel, r_ij, prm.H, prm.s_w)
        if r2 == 0.0:
            continue
        f = concentration_gradient_pair(m[j], prm.rho0, dw_dr_over_r(kernel, r_ij, prm.H, prm.s_g))
        gx += f * dx
        gy += f * dy
        gz += f * dz
    if c < SURFACE_CONCENTRATION:  # free-surface layer: grad C is the surface's, not disorder's
        gx = 0.0 * gx
        gy = 0.0 * gy
        gz = 0.0 * gz
    for q in range(wall_kind.shape[0]):  # near a wall: no shift along its normal
        d, nx, ny, nz = signed_distance(wall_kind[q], wall_data[q], x[i, 0], x[i, 1], x[i, 2])
        if d < prm.H:
            gn = gx * nx + gy * ny + gz * nz
            gx -= gn * nx
            gy -= gn * ny
            gz -= gn * nz
    speed = math.sqrt(v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1] + v[i, 2] * v[i, 2])
    s = -prm.shift_a * prm.h * speed
    if add:
        dv[i, 0] += s * gx
        dv[i, 1] += s * gy
        dv[i, 2] += s * gz
    else:
        dv[i, 0] = s * gx
        dv[i, 1] = s * gy
        dv[i, 2] = s * gz


@njit(cache=True, inline="always")
def integrate_row(integrator, use_drift, i, x, v, a, dv, dt, dt_prev):
    """Symplectic Euler: v += dt a; x += dt v.  Leapfrog KDK with staggered velocities:
    v_{n+1/2} = v_{n-1/2} + (dt_prev + dt)/2 a_n; x += dt v_{n+1/2}. XSPH adds dv to the drift."""
    if integrator == 0:
        kick = dt
    else:
        kick = 0.5 * (dt_prev + dt)
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
            s = 0.0 * L
        return lo + s
    return x


@njit(cache=True, inline="always")
def _reflect(v, i, c, vn, nc, prm):
    """Velocity component c after a wall contact: tangential part damped by friction, normal part
    reversed with restitution."""
    vt = v[i, c] - vn * nc
    v[i, c] = vt * (1.0 - prm.friction) - prm.restitution * vn * nc


@njit(cache=True, inline="always")
def boundaries_row(periodic, prm, i, x, v, lo, wall_kind, wall_data, leaked):
    """Wrap periodic axes; push a particle closer than wall_gap back out with restitution/friction;
    mark it in ``leaked`` if it was found behind a wall (d < 0).   (walls.py)"""
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
                vn = v[i, 0] * nx + v[i, 1] * ny + v[i, 2] * nz
                if vn < 0.0:
                    _reflect(v, i, 0, vn, nx, prm)
                    _reflect(v, i, 1, vn, ny, prm)
                    _reflect(v, i, 2, vn, nz, prm)
    leaked[i] = hit


@njit(cache=True, inline="always")
def statistics_row(i, x, v, a, rho, rho0):
    """(|v_i|^2, |a_i|^2, rho_i/rho0 - 1, finite) of row i; the step takes the maxima over rows."""
    v2 = v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1] + v[i, 2] * v[i, 2]
    a2 = a[i, 0] * a[i, 0] + a[i, 1] * a[i, 1] + a[i, 2] * a[i, 2]
    r = rho[i] / rho0 - 1.0
    s = v2 + a2 + r + x[i, 0] + x[i, 1] + x[i, 2]
    return v2, a2, r, math.isfinite(s)
