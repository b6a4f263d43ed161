"""Divergence-free SPH (DFSPH): an incompressible pressure solver (Bender & Koschier 2015, "Divergence-
free smoothed particle hydrodynamics", SCA; 2017, "Divergence-free SPH for incompressible and viscous
fluids", IEEE TVCG 23(3)).

Instead of an equation of state, pressure is solved for every step so that the fluid stays at rest
density. With kappa_i = p_i / rho_i^2 the symmetric pressure acceleration (``pressure.py``) is

    a_i = - sum_j m_j (kappa_i + kappa_j) grad W_ij - kappa_i g_i^wall

and the density changes at the rate (continuity equation, SPH form; walls at rest)

    D rho_i / Dt = sum_j m_j (v_i - v_j) . grad W_ij + g_i^wall . v_i

where g_i^wall = sum over the virtual wall lattice of m grad W = theta_i rho0 G0(d_i) n_i is the wall's
share of the kernel gradient (``walls.py``: the same virtual particles that give the wall its density
share). The wall carries no density constraint of its own, so its pressure term is the adjoint of its
share of the continuity equation (kappa_i once, as SPlisHSPlasH's DFSPH does for boundary
particles): the system stays symmetric. Mirroring the pressure (2 kappa_i, as the WCSPH wall does)
made it non-symmetric and the iteration diverged at the walls. Writing lambda_i = kappa_i dt^2, a
pressure update changes velocities by dv_i = -(1/dt) [sum_j m_j (lambda_i + lambda_j) grad W_ij +
lambda_i g_i^wall]. Keeping only particle i's own lambda (a Jacobi step), the density change it
causes at i is -lambda_i D_i with

    D_i = |G_i + g_i^wall|^2 + sum_j |m_j grad W_ij|^2,    G_i = sum_j m_j grad W_ij

(B&K's factor alpha_i = rho_i / D_i, with the wall term added), so each iteration sets

    lambda_i = omega s_i / max(D_i, d0),
        s_i = rho_i + dt D rho_i/Dt (v*) - rho0     (density solver: rho* -> rho0; closed flows:
                                                    the mean density, see reference_density)
        s_i = dt D rho_i/Dt (v)                      (divergence solver: D rho/Dt -> 0)

(omega = prm.dfsph_omega, d0 the full-neighbourhood D: see the constants below) and applies dv to
every particle; the two solvers iterate until the mean density error that an iteration removes,
|lambda_i| D_i / rho0, over all particles falls below their tolerance. With free surfaces (``sph.clamp_negative_pressure``) the sum of a particle's lambda over the solve is kept
>= 0 (projected Jacobi, as IISPH clamps pressure): a particle with a partial neighbourhood has a low
summed density and must not be pulled together, but pressure left from the warm start may fall.

Warm start (B&K 2017, section 4.3): the density solve first applies the previous step's kappa_i
(lambda_i = kappa_i dt^2, kappa carried with the particle as ``state.extra["kappa"]``), so a resting
column keeps its hydrostatic pressure and each step only corrects the change. The divergence solve
starts from zero. The reported pressure is p_i = rho_i^2 kappa_i, kappa_i = sum(lambda_i) / dt^2.

The step (``Simulation.stages``): density and D_i at the new positions; the divergence solver makes
v divergence-free there (B&K run it at the end of a step, after the neighbour search: the same place
in the cycle); non-pressure accelerations a_np; dt; v* = v + dt a_np; the density solver corrects v*;
x += dt v*. Time steps are limited by the flow speed, not by a speed of sound.
"""

from numba import njit
from sphcore.physics.pairs import mass_gradient, span_rows, spans, walk_start
from sphcore.physics.walls import near_wall, wall_density_gradient
from sphcore.physics.real import like

# The solvers' convergence test sums |s_i| / rho0 over all particles of all peers. Each row's share is
# counted in units of 2^-32 as an integer, so that the sum — and therefore the number of iterations —
# does not depend on the order of the additions (threads, blocks, peers): a run gives the same bits
# on one process or many. A row's share is capped at ERROR_CAP (so 10^8 rows cannot overflow int64).
ERROR_QUANTUM = 2.0 ** 32

# Jacobi relaxation omega. Relaxed Jacobi converges only if omega lambda_max / D < 2, and the SPH
# pressure operator's largest eigenvalue exceeds its diagonal by a ratio that grows with the number of
# neighbours (boundaries.lattice_jacobi_ratio: 2D Wendland C2 2.3 at 2.3 spacings, 5.7 at 4; 3D 3.3
# and 14). omega = min(RELAXATION_MAX, JACOBI_MARGIN / ratio) keeps the highest mode damped with a
# margin of 2 for the disorder of real particles. Measured: omega = 1 at 2.3 spacings (2D tank) blew
# up within 0.1 s; the fixed 0.5 used before blew up the Taylor-Green vortex at 3 and 4 spacings.
# 0.5 is IISPH's choice (Ihmsen et al. 2014).
RELAXATION_MAX = 0.5
JACOBI_MARGIN = 1.0


def relaxation(jacobi_ratio: float) -> float:
    """omega for a kernel whose lattice operator has lambda_max / D0 = ``jacobi_ratio``."""
    return min(RELAXATION_MAX, JACOBI_MARGIN / jacobi_ratio)
# D_i is floored at the full-neighbourhood value d0: a particle with a partial neighbourhood (free
# surface, wall) has a small D_i and would otherwise receive an overshooting lambda_i.
D_FLOOR = 1.0
# Every solve runs at least this many iterations (pressure updates), as SPlisHSPlasH's DFSPH does
# (its pressure solve at least 2, its divergence solve at least 1): the mean error is diluted by the
# many particles that need no correction, so without a minimum a thin compressed layer at a wall
# would never be corrected. The divergence solve's second minimum iteration cost two of a step's
# ~12 neighbour passes and changed nothing that the density solve does not correct next
# (docs/BENCHMARKS.md, 2026-12-05).
MIN_ITERATIONS = {"density": 2, "divergence": 1}
# How far a particle may move in one step (timestep.py, "displacement": max|v| dt + max|a| dt^2 <= L).
# The density prediction rho* = rho + dt D rho/Dt is linear in dt, the wall's share Phi(d) is not, and
# DFSPH's wall push acts only through the solve: fast particles crossed walls (found behind them and
# pushed back by the collision guard). L stays below the guard's distance (boundary.gap spacings), so
# that a particle the guard holds there cannot reach the wall in one step. Measured wall crossings:
# 2D dam break to t = 1.5 s at CFL 0.25 / 0.4 / 1.0 without the limit 0 / 4 / 52; tiny scene, 300
# steps at density tolerance 0.5 / 0.01 with L = 0.25 spacings in each of v dt and a dt^2: 2 / 2; with
# this bound at L = 0.8 gap = 0.2 spacings: 0 / 0.
MAX_DISPLACEMENT = 0.25   # spacings, when the scene has no guard distance (boundary.gap = 0)
GAP_SHARE = 0.8


def step_length(dx: float, gap: float) -> float:
    """L in m for a spacing dx and the guard distance ``gap`` (in spacings)."""
    return (GAP_SHARE * gap if gap > 0.0 else MAX_DISPLACEMENT) * dx
ERROR_CAP = 16.0


@njit(cache=True, inline="always")
def quantized_offset(rho_i, rho0):
    """rho_i / rho0 - 1 as a signed integer count of 2^-32 (capped at +-ERROR_CAP): summed over all
    particles of all peers in any order, the mean density of a closed flow (``reference_density``).
    In float64 whatever the run's precision (once per row): the quantum must be the same everywhere."""
    return int(max(-ERROR_CAP, min(rho_i / rho0 - 1.0, ERROR_CAP)) * ERROR_QUANTUM)


def reference_density(rho0: float, offset_sum: int, n: int) -> float:
    """The density the density solver drives a closed flow to: the mean summation density.

    In a flow without a free surface (periodic or walled all round: ``sph.clamp_negative_pressure``
    false) the volume is fixed, so the mean density cannot change; the mean of sum_j m_j W_ij still
    drifts from rho0 as the particles leave their lattice (a disordered set has a different kernel sum).
    A uniform density error has no pressure gradient that could remove it: solved against rho0, every
    step adds a uniform kappa, which grows without bound (Taylor-Green: 8e4 Pa after 0.12 s, then
    blow-up, because on disordered particles a uniform kappa still pushes). Solving against the mean
    removes only what a pressure gradient can remove (the compatibility condition of a Poisson
    problem without a Dirichlet boundary). ``offset_sum`` is the sum of quantized_offset."""
    return rho0 * (1.0 + offset_sum / ERROR_QUANTUM / max(n, 1))


@njit(cache=True, inline="always")
def quantized_error(e):
    """|s_i| / rho0 as an integer count of 2^-32 (capped at ERROR_CAP), formed in float64 whatever the
    run's precision (once per row): the quantum must be the same everywhere."""
    return int(min(e, ERROR_CAP) * ERROR_QUANTUM)


@njit(cache=True, inline="always")
def source(divergence, rho_i, rho_ref, rate, dt, share):
    """s_i: the density error the solver removes (module docstring). ``share`` = (dt / dt_flow)^2 < 1
    on a step shortened to land on an output time: a pressure acceleration moves a particle by ~dt^2,
    so a short step corrects that share of the present compression, not all of it with a velocity
    ~ (rho - rho0) / dt (which would also leave kappa = sum lambda / dt^2 huge for the next step).
    ``rho_ref`` is rho0, or in a closed flow the mean density (reference_density)."""
    if divergence:
        return dt * rate
    return share * (rho_i - rho_ref) + dt * rate


@njit(cache=True, inline="always")
def increment(clamp, dl, lam_sum_i):
    """This iteration's lambda_i: s_i / D_i, or with free surfaces the step that keeps the solve's sum
    of lambda_i >= 0 (projected Jacobi: pressure pushes, never pulls; it may fall back to 0)."""
    if clamp and lam_sum_i + dl < 0.0:
        return -lam_sum_i
    return dl


@njit(cache=True, inline="always")
def inverse_diagonal(gx, gy, gz, wx, wy, wz, sum_sq, d0):
    """1 / max(D_i, D_FLOOR d0) (module docstring); d0 is D of a full neighbourhood at rest."""
    d = (gx + wx) * (gx + wx) + (gy + wy) * (gy + wy) + (gz + wz) * (gz + wz) + sum_sq
    return like(d, 1.0) / max(d, like(d, D_FLOOR) * d0)


@njit(cache=True, inline="always")
def dfsph_factor_row(kernel, periodic, neighbours, pair_gradients, prm, i, x, m, rho, nbr, counts, cells, cell_begin,
                     cell_end, grad_w, wall_kind, wall_data, wall_tables, wall_near, fill, p, wgrad, inv_d, lam_sum):
    """DFSPH set-up of row i at the step's positions: the wall gradient g_i^wall, 1 / D_i, and p_i = 0
    (the forces stage then gives the non-pressure accelerations); returns rho_i / rho0 - 1 quantised
    (dfsph.quantized_offset; summed over all rows: the mean density). With ``pair_gradients`` the
    density pass stored m_j grad W_ij per list entry: this pass and the solves read it.   (dfsph.py)"""
    gx = like(prm.H, 0.0)
    gy = like(prm.H, 0.0)
    gz = like(prm.H, 0.0)
    sum_sq = like(prm.H, 0.0)
    home = walk_start(neighbours, x, i, cells)
    for span in range(spans(neighbours, cells)):
        k_lo, k_hi = span_rows(neighbours, span, home, i, counts, cells, cell_begin, cell_end)
        for k in range(k_lo, k_hi):
            j, wx, wy, wz, inside = mass_gradient(neighbours, pair_gradients, kernel, periodic, x, m, nbr, grad_w, i,
                                                  k, prm, cells)  # m_j grad W_ij
            if not inside:
                continue
            gx += wx
            gy += wy
            gz += wz
            sum_sq += wx * wx + wy * wy + wz * wz
    rho_i = rho[i]
    wx = like(rho_i, 0.0)  # zero, and not evaluated, in a cell no wall reaches (as the density pass's share)
    wy = like(rho_i, 0.0)
    wz = like(rho_i, 0.0)
    if near_wall(cells, wall_near, x, i):
        wx, wy, wz = wall_density_gradient(kernel, prm, wall_kind, wall_data, wall_tables, x, i, rho_i, fill[i])
    wgrad[i, 0] = wx
    wgrad[i, 1] = wy
    wgrad[i, 2] = wz
    inv_d[i] = inverse_diagonal(gx, gy, gz, wx, wy, wz, sum_sq, prm.dfsph_d0)
    p[i] = like(rho_i, 0.0)
    lam_sum[i] = like(rho_i, 0.0)  # the divergence solve starts from zero
    return quantized_offset(rho_i, prm.rho0)


@njit(cache=True, inline="always")
def dfsph_source_row(kernel, periodic, neighbours, pair_gradients, divergence, prm, i, x, v, m, rho, nbr, counts, cells,
                     cell_begin, cell_end, grad_w, wgrad, inv_d, dt, share, rho_ref, lam_sum, lam):
    """This iteration's lambda_i = s_i / D_i from the velocities v, projected so that the solve's sum
    stays >= 0 with free surfaces (dfsph.py); returns the density error it removes, |lambda_i| D_i / rho0,
    quantised (dfsph.quantized_error: an integer, so the sum over rows is the same in any order; 0 for a
    particle without neighbours: nothing to solve there)."""
    rate = wgrad[i, 0] * v[i, 0] + wgrad[i, 1] * v[i, 1] + wgrad[i, 2] * v[i, 2]
    found = 0  # neighbours of i
    home = walk_start(neighbours, x, i, cells)
    for span in range(spans(neighbours, cells)):
        k_lo, k_hi = span_rows(neighbours, span, home, i, counts, cells, cell_begin, cell_end)
        for k in range(k_lo, k_hi):
            j, wx, wy, wz, inside = mass_gradient(neighbours, pair_gradients, kernel, periodic, x, m, nbr, grad_w, i,
                                                  k, prm, cells)  # m_j grad W_ij
            if not inside:
                continue
            found += 1
            rate += (v[i, 0] - v[j, 0]) * wx + (v[i, 1] - v[j, 1]) * wy + (v[i, 2] - v[j, 2]) * wz
    s = source(divergence, rho[i], rho_ref, rate, dt, share)
    inv = inv_d[i]
    if found == 0:  # alone: no neighbour to push, nothing to solve
        lam[i] = like(s, 0.0)
        return quantized_error(like(s, 0.0))
    dl = increment(prm.clamp_negative, prm.dfsph_omega * s * inv, lam_sum[i])  # inv = 1 / max(D_i, d0)
    lam[i] = dl
    return quantized_error(abs(dl) / inv / prm.rho0)


@njit(cache=True, inline="always")
def dfsph_update_row(kernel, periodic, neighbours, pair_gradients, prm, i, x, m, lam, nbr, counts, cells, cell_begin,
                     cell_end, grad_w, wgrad, inv_dt, v, lam_sum):
    """v_i -= (1/dt) [sum_j m_j (lambda_i + lambda_j) grad W_ij + lambda_i g_i^wall];
    lam_sum_i += lambda_i.   (dfsph.py)"""
    l_i = lam[i]
    sx = l_i * wgrad[i, 0]
    sy = l_i * wgrad[i, 1]
    sz = l_i * wgrad[i, 2]
    home = walk_start(neighbours, x, i, cells)
    for span in range(spans(neighbours, cells)):
        k_lo, k_hi = span_rows(neighbours, span, home, i, counts, cells, cell_begin, cell_end)
        for k in range(k_lo, k_hi):
            j, wx, wy, wz, inside = mass_gradient(neighbours, pair_gradients, kernel, periodic, x, m, nbr, grad_w, i,
                                                  k, prm, cells)  # m_j grad W_ij
            if not inside:
                continue
            c = l_i + lam[j]
            sx += c * wx
            sy += c * wy
            sz += c * wz
    v[i, 0] -= inv_dt * sx
    v[i, 1] -= inv_dt * sy
    v[i, 2] -= inv_dt * sz
    lam_sum[i] += l_i


@njit(cache=True, inline="always")
def warm_lambda(kappa_i, dt):
    """lambda_i = kappa_i dt^2: the previous step's pressure, the density solve's warm start."""
    return kappa_i * dt * dt


@njit(cache=True, inline="always")
def dfsph_warm_ghost_row(i, kappa, dt, lam):
    """A ghost row's warm-start lambda from the kappa it carries (exchange 1): the bits its owner's
    kick gives it, with no message (a peer applies the warm start to its ghosts' pressure too)."""
    lam[i] = warm_lambda(kappa[i], dt)


@njit(cache=True, inline="always")
def dfsph_kick_row(i, v, a, dt, kappa, v_star, lam, lam_sum):
    """v*_i = v_i + dt a_i (non-pressure accelerations); the density solve's warm start is the
    previous step's pressure, lambda_i = kappa_i dt^2 (applied by one update before iterating)."""
    for c in range(3):
        v_star[i, c] = v[i, c] + dt * a[i, c]
    lam[i] = warm_lambda(kappa[i], dt)
    lam_sum[i] = like(dt, 0.0)


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
