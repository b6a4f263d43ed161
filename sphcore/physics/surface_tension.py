"""Surface tension from the colour field (Müller, Charypar & Gross 2003, section 4.4, eqs. 15-19).

The colour field c is 1 at particles and 0 elsewhere; smoothed, c_S(x) = sum_j m_j / rho_j W(x - x_j).
Its gradient n = grad c_S points into the fluid at the surface and its Laplacian gives the
curvature kappa = -lap c_S / |n|. The surface traction is a force density

    f_i = sigma kappa_i n_i / |n_i| = -sigma lap c_S(x_i) n_i / |n_i|,   applied where |n_i| > l

and the acceleration is a_i = f_i / rho_i. The threshold l (``normal_threshold`` in 1/m, scaled
by the scene) keeps the force off interior particles where n is noise. The gradient uses the
gradient kernel; the Laplacian uses the viscosity-kernel Laplacian, as Müller does for stability.
"""
from numba import njit
import math
from sphcore.physics.kernels import lap_w_viscosity, pair_dw_dr_over_r
from sphcore.physics.pairs import candidate, span_rows, spans, walk_start
from sphcore.physics.real import like


@njit(cache=True, inline="always")
def colour_gradient_pair(m_j, rho_j, dw_over_r):
    """Scalar f so that the contribution to n_i = grad c_S(x_i) is f * x_ij."""
    return m_j / rho_j * dw_over_r


@njit(cache=True, inline="always")
def colour_laplacian_pair(m_j, rho_j, lap):
    """Contribution of j to lap c_S(x_i)."""
    return m_j / rho_j * lap


@njit(cache=True, inline="always")
def surface_tension_factor(sigma, lap_c, n_norm, rho_i, threshold):
    """Scalar g so that a_i += g * n_i; zero away from the surface (|n| <= threshold)."""
    if n_norm <= threshold:
        return like(sigma, 0.0)
    return -sigma * lap_c / (n_norm * rho_i)


@njit(cache=True, inline="always")
def surface_tension_row(kernel, periodic, neighbours, prm, i, x, m, rho, nbr, counts, cells, cell_begin, cell_end, a):
    """Colour-field surface tension, a_i += -sigma lap c_i n_i / (|n_i| rho_i).   (surface_tension.py)"""
    gx = like(prm.H, 0.0)
    gy = like(prm.H, 0.0)
    gz = like(prm.H, 0.0)
    lap_c = like(prm.H, 0.0)
    home = walk_start(neighbours, x, i, cells)
    for span in range(spans(neighbours, cells)):
        k_lo, k_hi = span_rows(neighbours, span, home, i, counts, cells, cell_begin, cell_end)
        for k in range(k_lo, k_hi):
            j, dx, dy, dz, r2, inside = candidate(neighbours, periodic, x, nbr, i, k, prm, cells)
            if not inside:
                continue
            r_ij = math.sqrt(r2)
            f = colour_gradient_pair(m[j], rho[j], pair_dw_dr_over_r(kernel, r2, r_ij, prm.H, prm.s_g))
            gx += f * dx
            gy += f * dy
            gz += f * dz
            lap = colour_laplacian_pair(m[j], rho[j], lap_w_viscosity(r_ij, prm.H, prm.s_l))
            lap_c += lap if r2 > like(r2, 0.0) else like(lap, 0.0)  # coincident particles add nothing
    norm = math.sqrt(gx * gx + gy * gy + gz * gz)
    s = surface_tension_factor(prm.sigma, lap_c, norm, rho[i], prm.st_threshold)
    a[i, 0] += s * gx
    a[i, 1] += s * gy
    a[i, 2] += s * gz
