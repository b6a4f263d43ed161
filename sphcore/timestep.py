"""Time-step selection: fixed, or adaptive from the usual CFL-type limits of WCSPH.

Monaghan 1992 (section 10) and Morris et al. 1997 (eqs. 29-30), with h = H/2 the smoothing length:

    acoustic  dt_c = cfl * h / (c0 + max|v|)
    force     dt_f = cfl * sqrt(h / max|a|)
    viscous   dt_v = cfl * 0.5 * h^2 / nu        (physical viscosity models only)

The adaptive step is the smallest of these and the scene's ``time.dt`` (the largest allowed step);
the name of the binding limit is reported so users see what limits their run. An incompressible
solver (DFSPH) has no speed of sound: c0 = 0 makes the "acoustic" limit the flow-speed CFL
condition dt = cfl * h / max|v|.
"""
import math

LIMITS = ("acoustic", "force", "viscous", "max", "fixed", "until")


def choose_dt(mode: str, dt: float, cfl: float, h: float, c0: float, vmax: float, amax: float,
              nu: float) -> tuple[float, str]:
    """(dt, name of the binding limit) for mode 'fixed' or 'adaptive'."""
    if mode == "fixed":
        return dt, "fixed"
    best, name = dt, "max"
    acoustic = cfl * h / (c0 + vmax) if c0 + vmax > 0.0 else math.inf
    if acoustic < best:
        best, name = acoustic, "acoustic"
    if amax > 0.0:
        force = cfl * math.sqrt(h / amax)
        if force < best:
            best, name = force, "force"
    if nu > 0.0:
        viscous = cfl * 0.5 * h * h / nu
        if viscous < best:
            best, name = viscous, "viscous"
    return best, name
