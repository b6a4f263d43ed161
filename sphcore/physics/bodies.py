"""The fluid's force and torque on a floating body: the reaction to the wall terms of its wall
(``sph.body_force = "reaction"``, the default; the other way, the surface integral of the fluid's
traction, is physics/traction.py).

A floating obstacle (sphcore/motion.py FloatingBody) is an analytic wall like any other: it pushes
the particles near it with the wall pressure term and, with the Morris viscosity, drags them with
the no-slip term (physics/walls.py). By Newton's third law the fluid pushes the body back with

    F = - sum_i m_i (theta_i (a_i^wall pressure + a_i^wall viscous) + a_i^wall friction)     (that one wall's terms)

and turns it with the torque about its centre c (the wall's pivot, ``wall_motion[wall, 12:15]``)

    T = sum_i (x_i - c) x F_i,      F_i = - m_i (theta_i (...) + a_i^wall friction)

(theta_i the fill fraction, as in the forces pass; the turbulent friction of terms.wall_friction,
physics/wall_friction.py, is not scaled by it there, nor here). Each row returns its share in integer units of
``quantum`` newtons (N/m in 2D) and ``torque_quantum`` newton metres (N in 2D), so the sum over rows — and over peers, ``PeerHalo.reduce_sums`` —
is exact and independent of the order: every peer moves the body by the same bits. Where the body
meets another wall the corner correction of the walls' terms is not in F (the single-wall terms
are), a small error only while the body touches the container. (Comparable to the way DualSPHysics
sums the boundary particles' forces into a floating body: Crespo et al. 2015, section 3.)
"""
from numba import njit

from sphcore.physics.external import body_acceleration_at
from sphcore.physics.real import like
from sphcore.physics.wall_friction import wall_friction_acceleration
from sphcore.physics.walls import wall_terms, wall_viscosity


@njit(cache=True, inline="always")
def _units(value, quantum):
    """``value`` in integer units of ``quantum``, rounded to nearest (clamped far beyond any force)."""
    r = max(min(value / quantum, like(value, 2.0 ** 44)), like(value, -(2.0 ** 44)))  # 16 body weights per row
    if r >= 0.0:
        return int(r + like(r, 0.5))
    return -int(-r + like(r, 0.5))


@njit(cache=True, inline="always")
def body_reaction_row(kernel, viscosity, prm, i, x, v, m, rho, p, wall_kind, wall_data, wall_tables, wall_motion,
                      fill, dt_prev, wall, quantum, torque_quantum):
    """Row i's share of the fluid's force and torque on the body of wall row ``wall``: (Fx, Fy, Fz)
    in units of ``quantum`` N, (Tx, Ty, Tz) in units of ``torque_quantum`` N m.   (module docstring)"""
    bx, by, bz = body_acceleration_at(prm, x[i, 0], x[i, 1], x[i, 2])
    q0 = wall
    q1 = wall + 1
    _, ax, ay, az = wall_terms(kernel, prm, True, wall_kind[q0:q1], wall_data[q0:q1], wall_tables,
                               wall_motion[q0:q1], True, x[i, 0], x[i, 1], x[i, 2], p[i], rho[i], bx, by, bz)
    if viscosity == 3:  # Viscosity.MORRIS: the no-slip wall's drag
        kv, ux, uy, uz = wall_viscosity(prm, wall_kind[q0:q1], wall_data[q0:q1], wall_tables, wall_motion[q0:q1],
                                        x[i, 0], x[i, 1], x[i, 2], rho[i])
        ax += kv * v[i, 0] - ux
        ay += kv * v[i, 1] - uy
        az += kv * v[i, 2] - uz
    share = -m[i] * fill[i]
    fx, fy, fz = share * ax, share * ay, share * az
    if prm.wall_nu > 0.0:  # the walls' turbulent friction on row i from this wall
        tx, ty, tz = wall_friction_acceleration(prm, wall_kind[q0:q1], wall_data[q0:q1], wall_tables, wall_motion[q0:q1],
                                                x[i, 0], x[i, 1], x[i, 2], v[i, 0], v[i, 1], v[i, 2], dt_prev)
        fx -= m[i] * tx
        fy -= m[i] * ty
        fz -= m[i] * tz
    rx, ry, rz = x[i, 0] - wall_motion[wall, 12], x[i, 1] - wall_motion[wall, 13], x[i, 2] - wall_motion[wall, 14]
    return (_units(fx, quantum), _units(fy, quantum), _units(fz, quantum), _units(ry * fz - rz * fy, torque_quantum),
            _units(rz * fx - rx * fz, torque_quantum), _units(rx * fy - ry * fx, torque_quantum))
