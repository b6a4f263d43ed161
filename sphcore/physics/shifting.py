"""Fickian particle shifting (Lind, Xu, Stansby & Rogers 2012; diffusion coefficient of Skillen,
Lind, Stansby & Rogers 2013).

SPH particles following the flow's streamlines bunch up and leave gaps (in vortex cores and where
the pressure is negative), which ruins the kernel sums. Shifting moves each particle a little down
the gradient of the particle concentration C_i = sum_j V_j W_ij, like a diffusion:

    delta r_i = -D_i grad C_i,   grad C_i = sum_j V_j grad W_ij,   D_i = A h |v_i| dt,   V_j = m_j / rho0

with A of order 1-2 (the scene's ``terms.shifting``). The volumes are the lattice's, m_j / rho0 (Lind
et al. use m_j / rho_j in an incompressible scheme): with summation density, m_j / rho_j renormalises
C to ~1 even at a free surface, which would hide the surface from the test below. Here the shift is written as a drift velocity
dv_i = delta r_i / dt = -A h |v_i| grad C_i, added to the velocity that moves the particle (as XSPH's
correction is); the momentum equation is untouched. The drift diffuses the concentration with a
diffusivity ~A h |v|, so the step is limited to cfl h / (A max|v|) (sphcore/timestep.py): WCSPH's
acoustic step is smaller anyway, DFSPH's flow-speed step is not.

Near a free surface grad C points into the fluid because of the missing neighbours, not because
of disorder, and would push particles out of the fluid: in the free-surface layer (C_i below
``SURFACE_CONCENTRATION``) there is no shift (the simplest of the surface treatments of Lind et al.
2012, section 3.3). Near an analytic wall the wall-normal component is removed, so a shift never
pushes a particle towards a wall.
"""
from numba import njit

SURFACE_CONCENTRATION = 0.9  # C_i below this marks a particle of the free-surface layer


@njit(cache=True, inline="always")
def concentration_gradient_pair(m_j, rho0, dw_over_r):
    """Scalar f so that the contribution of j to grad C_i is f * x_ij."""
    return m_j / rho0 * dw_over_r
