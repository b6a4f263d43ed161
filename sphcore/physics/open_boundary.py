"""Open boundaries: a velocity inlet and an outlet, each a buffer zone of ordinary particles.

Inlet (the inflow buffer of Federico et al. 2012 and Tafuni et al. 2018): an axis-aligned box at the
domain's edge holds a lattice of particles moving at the inflow velocity U. A particle inside it has
v = U and a = 0 (and no drift correction): its position advances with U exactly. It takes part in
its neighbours' sums (density, pressure, viscosity) like any particle, so the fluid beside the zone
keeps a whole support; past the zone's front face it is fluid. New layers enter at the back face
(sphcore/open_boundary.py, on the host: their ids and positions follow from the time alone).

Outlet (a pressure outlet): a particle inside the box feels no force (a = 0): it moves on with
the velocity it came with, and its density and pressure are rho0 and the outlet's p_out (after
the EOS, before the ghosts' are exchanged), so the fluid upstream flows out against that pressure: it fixes
the pressure level of the flow, which the inlet's flux alone leaves free (the fluid would
otherwise compress until its own pressure pushed it out). A particle past the box's far face is
removed (host side).

- Federico, Marrone, Colagrossi, Aristodemo, Antuono, "Simulating 2D open-channel flows through an
  SPH model", Eur. J. Mech. B/Fluids 34 (2012) 35-46.
- Tafuni, Domínguez, Vacondio, Crespo, "A versatile algorithm for the treatment of open boundary
  conditions in Smoothed particle hydrodynamics GPU models", Comput. Methods Appl. Mech. Engrg. 342
  (2018) 604-624.

wall_zones: (nz, 10) rows [kind, lo (3), hi (3), U (3)] (m, m/s; an outlet: [7] is p_out in Pa); kind ZONE_INLET or ZONE_OUTLET, 0
for the one padding row of a scene without zones; an axis beyond the scene's dimension spans
(-ZONE_FAR, ZONE_FAR). A row is inside when lo <= x < hi on every axis (half-open: the zones tile).
"""
from numba import njit

from sphcore.physics.real import like

ZONE_NONE, ZONE_INLET, ZONE_OUTLET = 0, 1, 2
ZONE_COLUMNS = 10
ZONE_FAR = 1.0e30  # finite in float32


@njit(cache=True, inline="always")
def zone_of(i, x, wall_zones):
    """The row q of the zone that holds particle i, or -1."""
    for q in range(wall_zones.shape[0]):
        if int(wall_zones[q, 0]) == ZONE_NONE:  # int: a float32 table compared with a literal would promote
            continue
        if (wall_zones[q, 1] <= x[i, 0] < wall_zones[q, 4] and wall_zones[q, 2] <= x[i, 1] < wall_zones[q, 5]
                and wall_zones[q, 3] <= x[i, 2] < wall_zones[q, 6]):
            return q
    return -1


@njit(cache=True, inline="always")
def open_boundary_row(use_drift, i, x, v, a, dv, wall_zones):
    """Inlet: v = U, a = 0; outlet: a = 0; no drift correction in either (row i inside a zone)."""
    q = zone_of(i, x, wall_zones)
    if q < 0:
        return
    zero = like(x[i, 0], 0.0)
    for c in range(3):
        if int(wall_zones[q, 0]) == ZONE_INLET:
            v[i, c] = wall_zones[q, 7 + c]
        a[i, c] = zero
        if use_drift:
            dv[i, c] = zero


@njit(cache=True, inline="always")
def outlet_pressure_row(prm, i, x, rho, p, wall_zones):
    """rho = rho0, p = p_out for row i inside an outlet: what the fluid upstream sees of it. Its own
    density is not the fluid's: with a = 0 nothing keeps the zone's particles apart, and the slow
    ones beside a wall are caught up by faster ones (2.4 spacings across a zone 6 spacings long in
    configs/channel_2d.toml: 1.32 rho0 seen), which would set off the density checks."""
    q = zone_of(i, x, wall_zones)
    if q >= 0 and int(wall_zones[q, 0]) == ZONE_OUTLET:
        rho[i] = prm.rho0
        p[i] = wall_zones[q, 7]
