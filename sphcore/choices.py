"""Named choices a scene can make, and the integer codes the compiled drivers receive.

Scenes name choices as strings (``kernel = "wendland_c2"``); this module is the one registry that
maps those names to the IntEnum codes the compiled drivers hold as compile-time constants.
"""
from enum import IntEnum


class Kernel(IntEnum):
    """Smoothing kernel family (density kernel W and gradient kernel grad W)."""

    MULLER = 0        # Müller et al. 2003: poly6 for density, spiky for the pressure gradient
    CUBIC_SPLINE = 1  # Monaghan & Lattanzio 1985, support 2h
    WENDLAND_C2 = 2   # Wendland 1995 / Dehnen & Aly 2012, support 2h


class EOS(IntEnum):
    """Equation of state p(rho)."""

    LINEAR = 0  # p = k (rho - rho0), k = c0^2 (the seeds' "gas constant" form)
    TAIT = 1    # p = B ((rho/rho0)^7 - 1), B = rho0 c0^2 / 7 (Monaghan 1994, Batchelor 1967)


class Viscosity(IntEnum):
    """Viscosity model."""

    NONE = 0
    ARTIFICIAL = 1  # Monaghan 1992 artificial viscosity, parameter alpha
    MULLER = 2      # Müller 2003 viscosity-kernel Laplacian, kinematic viscosity nu
    MORRIS = 3      # Morris, Fox & Zhu 1997 laminar viscosity, kinematic viscosity nu


class PressureGradient(IntEnum):
    """The pressure gradient of the WCSPH momentum equation (physics/pressure.py)."""

    SYMMETRIC = 0   # Monaghan 1992: (p_i / rho_i^2 + p_j / rho_j^2), conserves momentum
    DIFFERENCE = 1  # (p_j - p_i) / (rho_i rho_j) in the bulk, symmetric in the free-surface layer
    # Not a scene value: DFSPH's solves apply the pressure (physics/dfsph.py) and its forces pass runs
    # with p = 0, so the model compiles that pass without the pair term (every pair added exactly 0)
    SOLVED = 2


class Integrator(IntEnum):
    SYMPLECTIC_EULER = 0
    LEAPFROG = 1  # kick-drift-kick, velocities stored at half steps


class WallKind(IntEnum):
    """Analytic boundary primitives (see sphcore.physics.walls)."""

    PLANE = 0             # fluid on the side the normal points to
    SPHERE_INSIDE = 1     # spherical container: fluid inside
    CYLINDER_INSIDE = 2   # lateral surface of a cylindrical container (local y axis)
    SPHERE_OUTSIDE = 3    # spherical obstacle: fluid outside
    BOX_OUTSIDE = 4       # box obstacle (rotated): fluid outside
    MESH_OUTSIDE = 5      # triangle-mesh obstacle: a signed distance grid (sphcore.mesh_sdf)


KERNELS = {"muller": Kernel.MULLER, "cubic_spline": Kernel.CUBIC_SPLINE, "wendland_c2": Kernel.WENDLAND_C2}
EOSES = {"linear": EOS.LINEAR, "tait": EOS.TAIT}
VISCOSITIES = {"none": Viscosity.NONE, "artificial": Viscosity.ARTIFICIAL, "muller": Viscosity.MULLER,
               "morris": Viscosity.MORRIS}
PRESSURE_GRADIENTS = {"symmetric": PressureGradient.SYMMETRIC, "difference": PressureGradient.DIFFERENCE}
INTEGRATORS = {"symplectic_euler": Integrator.SYMPLECTIC_EULER, "leapfrog": Integrator.LEAPFROG}
