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
        s_i = rho_i + dt D rho_i/Dt (v*) - rho0     (density solver: rho* -> rho0)
        s_i = dt D rho_i/Dt (v)                      (divergence solver: D rho/Dt -> 0)

(omega = RELAXATION, d0 the full-neighbourhood D: see the constants below) and applies dv to every particle; the two solvers iterate until the mean density error that an
iteration removes, |lambda_i| D_i / rho0, over all particles falls below their tolerance. With free
surfaces (``sph.clamp_negative_pressure``) the sum of a particle's lambda over the solve is kept
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

# The solvers' convergence test sums |s_i| / rho0 over all particles of all peers. Each row's share is
# counted in units of 2^-32 as an integer, so that the sum — and therefore the number of iterations —
# does not depend on the order of the additions (threads, blocks, peers): a run gives the same bits
# on one process or many. A row's share is capped at ERROR_CAP (so 10^8 rows cannot overflow int64).
ERROR_QUANTUM = 2.0 ** 32

# Jacobi relaxation: without it the iteration diverges (the SPH pressure operator's high-frequency
# eigenvalues exceed twice its diagonal); 0.5 as in IISPH (Ihmsen et al. 2014). Measured on the
# hydrostatic tank: 1.0 blows up within 0.1 s, 0.5 converges.
RELAXATION = 0.5
# D_i is floored at the full-neighbourhood value d0: a particle with a partial neighbourhood (free
# surface, wall) has a small D_i and would otherwise receive an overshooting lambda_i.
D_FLOOR = 1.0
# Every solve runs at least this many iterations (as SPlisHSPlasH does): the mean error is diluted
# by the many particles that need no correction, so without a minimum a thin compressed layer at a
# wall would never be corrected.
MIN_ITERATIONS = 2
ERROR_CAP = 16.0


@njit(cache=True, inline="always")
def quantized_error(e):
    """|s_i| / rho0 as an integer count of 2^-32 (capped at ERROR_CAP)."""
    return int(min(e, ERROR_CAP) * ERROR_QUANTUM)


@njit(cache=True, inline="always")
def density_rate_pair(m_j, dvx, dvy, dvz, gx, gy, gz):
    """m_j (v_i - v_j) . grad W_ij: neighbour j's share of D rho_i / Dt (grad W_ij = (gx, gy, gz))."""
    return m_j * (dvx * gx + dvy * gy + dvz * gz)


@njit(cache=True, inline="always")
def source(divergence, rho_i, rho0, rate, dt, share):
    """s_i: the density error the solver removes (module docstring). ``share`` = (dt / dt_flow)^2 < 1
    on a step shortened to land on an output time: a pressure acceleration moves a particle by ~dt^2,
    so a short step corrects that share of the present compression, not all of it with a velocity
    ~ (rho - rho0) / dt (which would also leave kappa = sum lambda / dt^2 huge for the next step)."""
    if divergence:
        return dt * rate
    return share * (rho_i - rho0) + dt * rate


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
    return 1.0 / max(d, D_FLOOR * d0)
