"""Smoothing kernels W(r, H) and their radial derivatives dW/dr, in 2D and 3D.

All kernels here have compact support: W = 0 for r >= H, where H is the *support radius*
(``Params.H``). Normalisation constants depend on the dimension and on H only; they are computed
once by :func:`kernel_constants` and travel in ``Params`` so that the pair functions do no powers.

Families (``sphcore.choices.Kernel``):

* ``MULLER`` — Müller, Charypar & Gross 2003, "Particle-based fluid simulation for interactive
  applications", eqs. (20)-(22): density with poly6, pressure gradient with spiky (Desbrun &
  Gascuel 1996), viscosity with the Laplacian of the viscosity kernel::

      W_poly6(r)  = s_w (H^2 - r^2)^3          s_w = 315/(64 pi H^9)  (3D),  4/(pi H^8) (2D)
      W_spiky(r)  = s_g (H - r)^3              s_g = 15/(pi H^6)      (3D), 10/(pi H^5) (2D)
      lap W_visc  = s_l (H - r)                s_l = 45/(pi H^6)      (3D), 40/(pi H^5) (2D)

  The 2D Laplacian constant follows from the same second-moment condition that gives Müller's 3D
  constant, integral(lap W * x^2 dV) = 2, so that sum_j V_j (v_j - v_i) lap W_ij -> lap v.

* ``CUBIC_SPLINE`` — Monaghan & Lattanzio 1985 (Monaghan 1992, eq. 2.6), h = H/2, q = r/h::

      W = s (1 - 3/2 q^2 + 3/4 q^3)   0 <= q < 1        s = 1/(pi h^3) (3D), 10/(7 pi h^2) (2D)
      W = s/4 (2 - q)^3               1 <= q < 2

* ``WENDLAND_C2`` — Wendland 1995, normalised as in Dehnen & Aly 2012 (table 1), q = r/H::

      W = s (1 - q)^4 (1 + 4 q)                         s = 21/(2 pi H^3) (3D), 7/(pi H^2) (2D)

For the cubic spline and Wendland C2 the same kernel serves density and gradient (s_g = s_w).
"""
import math

from numba import njit

from sphcore.choices import Kernel
from sphcore.physics.real import like


def kernel_constants(kernel: Kernel, dim: int, H: float) -> tuple[float, float, float]:
    """Return (s_w, s_g, s_l): density-kernel, gradient-kernel and viscosity-Laplacian constants."""
    if dim not in (2, 3):
        raise ValueError(f"dimension must be 2 or 3, got {dim}")
    pi = math.pi
    s_l = 45.0 / (pi * H**6) if dim == 3 else 40.0 / (pi * H**5)
    if kernel == Kernel.MULLER:
        if dim == 3:
            return 315.0 / (64.0 * pi * H**9), 15.0 / (pi * H**6), s_l
        return 4.0 / (pi * H**8), 10.0 / (pi * H**5), s_l
    if kernel == Kernel.CUBIC_SPLINE:
        h = 0.5 * H
        s = 1.0 / (pi * h**3) if dim == 3 else 10.0 / (7.0 * pi * h**2)
        return s, s, s_l
    if kernel == Kernel.WENDLAND_C2:
        s = 21.0 / (2.0 * pi * H**3) if dim == 3 else 7.0 / (pi * H**2)
        return s, s, s_l
    raise ValueError(f"unknown kernel {kernel!r}")


@njit(cache=True, inline="always")
def w(kernel, r, H, s_w):
    """Density kernel W(r) of the family ``kernel`` (poly6 for MULLER)."""
    if r >= H:
        return like(s_w, 0.0)
    if kernel == 0:  # Kernel.MULLER: poly6
        d = H * H - r * r
        return s_w * d * d * d
    elif kernel == 1:  # Kernel.CUBIC_SPLINE
        q = like(r, 2.0) * r / H
        if q < like(q, 1.0):
            return s_w * (like(q, 1.0) - like(q, 1.5) * q * q + like(q, 0.75) * q * q * q)
        t = like(q, 2.0) - q
        return like(s_w, 0.25) * s_w * t * t * t
    else:  # Kernel.WENDLAND_C2
        q = r / H
        t = like(q, 1.0) - q
        t2 = t * t
        return s_w * t2 * t2 * (like(q, 1.0) + like(q, 4.0) * q)


@njit(cache=True, inline="always")
def dw_dr(kernel, r, H, s_g):
    """Radial derivative dW/dr of the gradient kernel (spiky for MULLER); grad W = dW/dr * x_ij / r."""
    if r >= H:
        return like(s_g, 0.0)
    if kernel == 0:  # Kernel.MULLER: spiky
        t = H - r
        return like(s_g, -3.0) * s_g * t * t
    elif kernel == 1:  # Kernel.CUBIC_SPLINE
        h = like(H, 0.5) * H
        q = r / h
        if q < like(q, 1.0):
            return s_g / h * (like(q, -3.0) * q + like(q, 2.25) * q * q)
        t = like(q, 2.0) - q
        return like(s_g, -0.75) * s_g / h * t * t
    else:  # Kernel.WENDLAND_C2
        q = r / H
        t = like(q, 1.0) - q
        return like(s_g, -20.0) * s_g / H * q * t * t * t


@njit(cache=True, inline="always")
def dw_dr_over_r(kernel, r, H, s_g):
    """(dW/dr) / r, so that grad W = dw_dr_over_r * x_ij. Division-free for the cubic spline (inner
    part) and Wendland C2: divisions bound the force pass, several per pair otherwise."""
    if r >= H:
        return like(s_g, 0.0)
    if kernel == 0:  # Kernel.MULLER: spiky
        t = H - r
        return like(s_g, -3.0) * s_g * t * t / r
    elif kernel == 1:  # Kernel.CUBIC_SPLINE
        h = like(H, 0.5) * H
        q = r / h
        if q < like(q, 1.0):
            return s_g / (h * h) * (like(q, -3.0) + like(q, 2.25) * q)
        t = like(q, 2.0) - q
        return like(s_g, -0.75) * s_g / h * t * t / r
    else:  # Kernel.WENDLAND_C2: dW/dr = -20 s q (1-q)^3 / H and q / r = 1 / H
        q = r / H
        t = like(q, 1.0) - q
        return like(s_g, -20.0) * s_g / (H * H) * t * t * t


@njit(cache=True, inline="always")
def pair_dw_dr_over_r(kernel, r2, r, H, s_g):
    """dw_dr_over_r of a pair at distance r (r2 = r^2 m^2), and 0 for coincident particles (r = 0: no
    direction, no gradient). A pair loop that takes 0 here instead of skipping the pair with a
    `continue` has no branch left, and LLVM vectorises it: the 3D dam break's float32 force pass took
    7.2 ms instead of 14.4 at one thread (docs/BENCHMARKS.md, 2026-12-06). Every pair term built on it
    is proportional to it, so a coincident pair adds exactly 0, as skipped."""
    return dw_dr_over_r(kernel, r, H, s_g) if r2 > like(r2, 0.0) else like(s_g, 0.0)


@njit(cache=True, inline="always")
def lap_w_viscosity(r, H, s_l):
    """Laplacian of Müller's viscosity kernel, s_l (H - r) for r < H (Müller 2003 eq. 22)."""
    if r >= H:
        return like(s_l, 0.0)
    return s_l * (H - r)
