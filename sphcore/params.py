"""Physical parameters as a flat NamedTuple of scalars, cast to the run's precision.

numba passes NamedTuples to CPU drivers (and to CUDA kernels) by value; every float field is cast to
the run's dtype so that float32 runs compute in float32 where the arithmetic allows it. Vectors are
spelled out per component: numba's parallel loops do not accept tuples nested in a NamedTuple.
"""
from typing import NamedTuple

import numpy as np


class Params(NamedTuple):
    H: float            # support radius (m)
    h: float            # smoothing length H/2 (m), used by the viscosity regularisation
    s_w: float          # density-kernel constant (kernels.kernel_constants)
    s_g: float          # gradient-kernel constant
    s_l: float          # viscosity-Laplacian constant
    w0: float           # W(0): the self contribution to density per unit mass
    rho0: float         # rest density (kg/m^3)
    c0: float           # speed of sound (m/s)
    clamp_negative: bool
    alpha: float        # Monaghan artificial viscosity coefficient
    mu: float           # dynamic viscosity rho0 * nu (Pa s)
    gravity_x: float    # gravitational acceleration (m/s^2)
    gravity_y: float
    gravity_z: float
    external_x: float   # constant external acceleration (m/s^2)
    external_y: float
    external_z: float
    central_omega2: float  # omega^2 of the central force field a = -omega^2 (x - c) (1/s^2); 0 = off
    central_x: float    # its centre c (m)
    central_y: float
    central_z: float
    period_x: float     # period length along x, 0 if x is not periodic (m)
    period_y: float
    period_z: float
    xsph_eps: float
    shift_a: float      # particle shifting coefficient A (physics/shifting.py)
    sigma: float        # surface tension coefficient (N/m)
    st_threshold: float # colour-gradient threshold (1/m)
    vorticity_eps: float
    restitution: float
    friction: float
    wall_gap: float     # closest approach to a wall before collision handling (m)
    dx: float           # initial lattice spacing (m): the virtual wall lattice
    inv_s: float        # 1 / S, S = full-lattice kernel sum (1/m^dim); mass m = rho0 / S
    dim3: bool          # True for 3D scenes
    wall_table_end: float  # wall tables span d in [0, wall_table_end] (m), boundaries.table_end
    dfsph_d0: float     # DFSPH diagonal of a full neighbourhood (boundaries.lattice_pressure_diagonal; kg^2/m^8 in 3D)
    dfsph_omega: float  # DFSPH Jacobi relaxation (physics/dfsph.relaxation)
    delta_hc0: float    # delta-SPH diffusion factor delta h c0 (m^2/s; physics/continuity.py)
    wall_nu: float      # the walls' turbulent friction: nu of its law of the wall (m^2/s; 0 = off; physics/wall_friction.py)
    p_background: float  # background pressure p_b added to the EOS pressure (Pa; physics/eos.py; 0 = off)


def make_params(dtype, **values) -> Params:
    """Build Params with every float cast to ``dtype``; vector values (gravity=(x, y, z)) are split
    into their ``_x``, ``_y``, ``_z`` fields."""
    cast = np.dtype(dtype).type
    flat = {}
    for name, v in values.items():
        if isinstance(v, (tuple, list, np.ndarray)):
            for axis, e in zip("xyz", v):
                flat[f"{name}_{axis}"] = e
        else:
            flat[name] = v
    return Params(**{name: flat[name] if isinstance(flat[name], bool) else cast(flat[name])
                     for name in Params._fields})
