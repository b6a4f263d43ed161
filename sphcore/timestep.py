"""Time-step selection: fixed, or adaptive from the usual CFL-type limits of WCSPH.

Monaghan 1992 (section 10) and Morris et al. 1997 (eqs. 29-30), with h = H/2 the smoothing length:

    acoustic  dt_c = cfl * h / (c0 + max|v|)
    force     dt_f = cfl * sqrt(h / max|a|)
    viscous   dt_v = cfl * 0.5 * h^2 / nu        (physical viscosity models only)
    shifting  dt_s = cfl * h / (A max|v|)        (particle shifting only)
    displacement max|v| dt_d + max|a| dt_d^2 = L     (DFSPH only: no particle moves more than L)

The shifting limit: Fickian shifting (physics/shifting.py) moves particles with the drift velocity
-A h |v| grad C, a diffusion of the particle concentration with diffusivity ~A h |v|. Like any
explicit diffusion it is stable only while A |v| dt / h stays small; with a speed of sound in the
acoustic limit WCSPH never gets there, but DFSPH's flow-speed step does: the Taylor-Green vortex
with A = 8 blew up at DFSPH's step (A |v| dt / h = 2) and ran at A = 1 (0.25).

The displacement limit: DFSPH predicts a particle's density linearly in dt, and the analytic walls'
share of it is far from linear within a spacing of the wall; particles that move a good part of a
spacing in one step cross walls (found behind them and pushed back by the collision guard). L is
below the guard's distance boundary.gap (dfsph.step_length): a particle the guard holds at that
distance cannot reach the wall in one step. It is not scaled by cfl: it is where walls stop working,
whatever the accuracy asked for.

The adaptive step is the smallest of these and the scene's ``time.dt`` (the largest allowed step);
the name of the binding limit is reported so users see what limits their run. An incompressible
solver (DFSPH) has no speed of sound: c0 = 0 makes the "acoustic" limit the flow-speed CFL
condition dt = cfl * h / max|v|.
"""
import math

LIMITS = ("acoustic", "force", "viscous", "shifting", "displacement", "max", "fixed", "until")


def choose_dt(mode: str, dt: float, cfl: float, h: float, c0: float, vmax: float, amax: float,
              nu: float, shift_a: float = 0.0, max_step_length: float = 0.0) -> tuple[float, str]:
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
    if shift_a > 0.0 and vmax > 0.0:
        shifting = cfl * h / (shift_a * vmax)
        if shifting < best:
            best, name = shifting, "shifting"
    if max_step_length > 0.0 and (vmax > 0.0 or amax > 0.0):
        L = max_step_length
        if amax > 0.0:  # the positive root of amax dt^2 + vmax dt - L = 0, written without cancellation
            displacement = 2.0 * L / (vmax + math.sqrt(vmax * vmax + 4.0 * amax * L))
        else:
            displacement = L / vmax
        if displacement < best:
            best, name = displacement, "displacement"
    return best, name
