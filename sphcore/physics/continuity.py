"""Density by the continuity equation, with delta-SPH density diffusion and its hydrostatic
correction (``sph.density = "continuity"``).

    D rho_i / Dt = sum_j m_j (v_i - v_j) . grad W_ij + rho0 grad Phi_i . v_i          (Monaghan 1992, eq. 2.7)
                 + delta h c0 sum_j psi_ij . grad W_ij m_j / rho_j                     (Molteni & Colagrossi 2009)
    psi_ij = 2 (rho_ji - rho^H_ji) x_ji / |x_ij|^2,   rho_ji = rho_j - rho_i,   x_ji = x_j - x_i
    rho^H_ji = rho g . x_ji / c^2(rho),   rho = (rho_i + rho_j) / 2                (Fourtakas et al. 2019)

Why: with summation density (density.py) rho_i is a function of where the neighbours happen to sit,
and a weakly compressible pressure amplifies it by c0^2: in a settled tank 0.1 % of density scatter
from the particles' arrangement is 20 % of rho0 g H in single-particle pressure, and the scatter does
not decay with time (docs/VALIDATION.md). Integrated density carries no arrangement noise of its
own, and the diffusion term removes the high-frequency density noise that the continuity equation
accumulates (Antuono et al. 2010 analyse it as delta-SPH; delta = 0.1 is their standard value).

The diffusion alone would also diffuse the hydrostatic density gradient rho0 g / c0^2 in a column at
rest, pulling a resting column's density towards uniform and producing a spurious flux at the free
surface and the walls; Fourtakas et al. subtract the hydrostatic part of each pair's difference, so
a column at hydrostatic rest has no diffusion at all. rho^H_ji here is the density step of the
hydrostatic pressure step rho g . x_ji at the pair's own state, with the EOS's local c^2 = dp/drho
(eos.sound_speed_sq): Fourtakas et al. take it at rho0, which for Tait (c^2 = c0^2 (rho/rho0)^6) is
off by 6 (rho/rho0 - 1), 3 % at the floor of a 0.5 m tank with c0 = 31 m/s (on that tank the two
forms settled to the same profile within the measurement; the local one is the exact step). The
pair's mean density keeps rho^H_ji antisymmetric (mass is conserved). Only gravity enters it (the body force a column at
rest balances).

Walls: the analytic wall's share of the density, rho0 Phi(d_i) theta_i (walls.py), changes as the
particle moves, rho0 grad Phi . v_i: the same wall gradient g^wall as DFSPH's (dfsph.dfsph_factor_row).
No density diffuses through a wall.

rho is carried with the particle (``state.extra["density"]``): sorted with the grid, migrated,
rebalanced and checkpointed. A row whose carried density is 0 (a new run, or a checkpoint written by
a summation run) starts at rho0: a scene's particles start on the lattice whose kernel sum defines
their mass, at rest density. Not from the kernel sum: at a free surface the sum is ~30 % short, and
the diffusion then drained that deficit into the column for seconds (a tank settled 1.7 % of
rho0 g H below the hydrostatic line).

A floor: the carried density never falls below m_i W(0), the particle's own share of its kernel sum
(the least density the summation could give it; density.py). The rate above does not shrink with
rho_i, so a particle thrown off as spray, its few neighbours moving apart, integrates its density
towards zero and past it (0.02 rho0 in MARIN's 3D dam break at H0 / 15 by t = 0.9 s); the diffusion
term's m_j / rho_j of such a neighbour then grew without bound, and one step took a neighbour from
0.09 rho0 to 212 rho0 (docs/VALIDATION.md, the MARIN section). Spray is below rest density, at
p = 0 with the clamp, with or without the floor; the floor only keeps its volume finite.

Time integration: a symplectic pair with the velocity, like x. Step n computes the pressure from
rho_n and kicks v; x moves with v_{n+1}; the next step's density pass advances the carried density
with that same v_{n+1} at x_{n+1}: rho_{n+1} = rho_n + dt_n D rho/Dt (``density_row``, dt_prev).
Advancing it inside step n with v_n instead (forward Euler for the acoustic pair rho, v) made a
resting tank's kinetic energy grow without bound. The diffusion term, dissipative, is explicit: it is
computed after the ghosts' densities arrive and added with the step's dt (``diffusion_row``,
``density_update_row``).
"""
import math

from numba import njit
from sphcore.physics.eos import sound_speed_sq
from sphcore.physics.kernels import pair_dw_dr_over_r
from sphcore.physics.pairs import candidate, span_rows, spans, walk_start
from sphcore.physics.real import like


@njit(cache=True, inline="always")
def density_rate_pair(m_j, dvx, dvy, dvz, gx, gy, gz):
    """m_j (v_i - v_j) . grad W_ij: neighbour j's share of D rho_i / Dt (grad W_ij = (gx, gy, gz))."""
    return m_j * (dvx * gx + dvy * gy + dvz * gz)


@njit(cache=True, inline="always")
def hydrostatic_difference(rho, c_sq, gx, gy, gz, x_jix, x_jiy, x_jiz):
    """rho^H_ji = rho g . x_ji / c^2: the density difference of hydrostatic rest between j and i."""
    return rho * (gx * x_jix + gy * x_jiy + gz * x_jiz) / c_sq


@njit(cache=True, inline="always")
def diffusion_pair(m_j, rho_i, rho_j, hydrostatic_ji, dw_over_r):
    """Neighbour j's share of the delta term without its factor delta h c0:
    psi_ij . grad W_ij m_j / rho_j = -2 (rho_ji - rho^H_ji) dW/dr / r m_j / rho_j (x_ji . x_ij = -r^2)."""
    return like(rho_j, -2.0) * (rho_j - rho_i - hydrostatic_ji) * dw_over_r * m_j / rho_j


@njit(cache=True, inline="always")
def diffusion_row(kernel, eos, periodic, neighbours, prm, i, x, m, rho, nbr, counts, cells, cell_begin, cell_end, drho):
    """drho_i = the delta-SPH density diffusion with its hydrostatic correction.   (continuity.py)"""
    rho_i = rho[i]
    diff = like(rho_i, 0.0)
    home = walk_start(neighbours, x, i, cells)
    for span in range(spans(neighbours, cells)):
        k_lo, k_hi = span_rows(neighbours, span, home, i, counts, cells, cell_begin, cell_end)
        for k in range(k_lo, k_hi):
            j, dx, dy, dz, r2, inside = candidate(neighbours, periodic, x, nbr, i, k, prm, cells)
            if not inside:
                continue
            g = pair_dw_dr_over_r(kernel, r2, math.sqrt(r2), prm.H, prm.s_g)  # 0 for coincident particles
            # (dx, dy, dz) = x_i - x_j; the pair's mean density sets the hydrostatic step (symmetric in i, j)
            rho_m = like(rho_i, 0.5) * (rho_i + rho[j])
            hydro = hydrostatic_difference(rho_m, sound_speed_sq(eos, rho_m, prm.rho0, prm.c0),
                                           prm.gravity_x, prm.gravity_y, prm.gravity_z, -dx, -dy, -dz)
            diff += diffusion_pair(m[j], rho_i, rho[j], hydro, g)
    drho[i] = prm.delta_hc0 * diff


@njit(cache=True, inline="always")
def density_update_row(i, rho_c, drho, dt):
    """rho_i += dt drho_i (the carried density; continuity.py)."""
    rho_c[i] += dt * drho[i]
