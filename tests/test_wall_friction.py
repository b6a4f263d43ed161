"""Turbulent wall friction (terms.wall_friction, sphcore/physics/wall_friction.py): Spalding's law of
the wall inverted for u_tau, the wall stress spread over the particles near a wall so that a lattice
column takes exactly rho0 u_tau^2 of its wall area, relative to the wall's own velocity."""
import math

import numpy as np
import pytest

from sphcore.boundaries import wall_tables
from sphcore.choices import Kernel
from sphcore.physics.kernels import kernel_constants, w
from sphcore.physics.wall_friction import B_SMOOTH, KAPPA, OMEGA_ROW, spalding_u_plus
from sphcore.scene import load_scene
from sphcore.solver import Simulation

from conftest import CONFIGS

pytestmark = pytest.mark.fast


def _y_plus(u):
    """Spalding (1961): y+ as a function of u+."""
    k = KAPPA * u
    return u + math.exp(-KAPPA * B_SMOOTH) * (math.exp(k) - 1.0 - k - k * k / 2.0 - k ** 3 / 6.0)


def _u_plus_by_bisection(R):
    lo, hi = 0.0, min(max(1.0, math.sqrt(R)), 100.0)  # u+ < 50 for R < 1e10
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if mid * _y_plus(mid) < R else (lo, mid)
    return 0.5 * (lo + hi)


@pytest.mark.parametrize("R", [1e-3, 0.1, 1.0, 30.0, 1e3, 1e5, 1e8])
def test_spalding_law_is_inverted_to_round_off(R):
    u = spalding_u_plus(R)
    assert u * _y_plus(u) == pytest.approx(R, rel=1e-12)
    assert u == pytest.approx(_u_plus_by_bisection(R), rel=1e-12)
    assert spalding_u_plus(np.float32(R)) == pytest.approx(u, rel=1e-5)  # float32 converges too


def test_the_law_has_its_viscous_sublayer_and_its_log_layer():
    # Given a tiny and a large local Reynolds number R = y U / nu = u+ y+
    # Then u+ = y+ in the sublayer and u+ = ln(y+) / kappa + B in the log layer
    u = spalding_u_plus(1e-4)
    assert u == pytest.approx(math.sqrt(1e-4), rel=1e-3)
    u = spalding_u_plus(1e7)
    assert u == pytest.approx(math.log(_y_plus(u)) / KAPPA + B_SMOOTH, rel=1e-3)
    assert spalding_u_plus(0.0) == 0.0


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("support", [2.0, 2.3, 3.0])
def test_a_lattice_column_takes_exactly_its_wall_areas_stress(dim, support):
    # Given the wall tables of a lattice (mass rho0 / S per particle) next to a flat wall
    dx = 0.01
    H = support * dx
    tables = wall_tables(Kernel.WENDLAND_C2, dim, H, dx)
    end = math.ceil(H / (0.5 * dx) - 1e-9) * 0.5 * dx
    d = np.linspace(0.0, end, tables.shape[1])
    s_w = kernel_constants(Kernel.WENDLAND_C2, dim, H)[0]
    K = int(math.ceil(H / dx)) + 1
    lattice = np.arange(-K, K + 1) * dx
    grids = np.meshgrid(*([lattice] * dim), indexing="ij")
    S = sum(w(int(Kernel.WENDLAND_C2), r, H, s_w) for r in np.sqrt(sum(g ** 2 for g in grids)).ravel())
    # Then the stress shares of the rows at (k + 1/2) dx sum to S dx^(dim-1): sum_k m omega_k = rho0 dx^(dim-1)
    rows = (np.arange(K + 1) + 0.5) * dx
    shares = np.interp(rows[rows < end], d, tables[OMEGA_ROW])
    assert shares.sum() == pytest.approx(S * dx ** (dim - 1), rel=1e-9)
    # and nothing reaches beyond the support
    assert tables[OMEGA_ROW][d >= H].max(initial=0.0) == 0.0


def test_a_sliding_plate_pulls_the_fluid_by_the_law_of_the_wall_and_a_still_one_does_not():
    # Given fluid at rest between a plate at rest (y = 0) and one sliding at U (y = 1 mm), x periodic,
    # no viscosity of its own, water's nu in the wall law
    U, nu, dx = 0.5, 1.0e-6, 5.0e-5
    # (the choices of test_stages' drag test, whose kernels the suite has compiled by then)
    sc = load_scene(CONFIGS / "couette_2d.toml", [f"particles.spacing={dx}", "sph.viscosity='none'", "sph.eos='tait'",
                                                  "time.integrator='symplectic_euler'", "sph.sound_speed=5.0",
                                                  f"domain.planes[1].velocity=[{U}, 0.0]", f"terms.wall_friction={nu}"])
    sim = Simulation(sc, "f64")
    # When the accelerations are computed
    sim.refresh()
    s = sim.state
    n = s.n_owned
    y, ax, m = s.x[:n, 1], s.a[:n, 0], s.m[:n]
    # Then the layer under the sliding plate is pulled along it with the stress the law gives at each
    # row's distance, shared as the wall tables share it: rho0 sum_k f_k u_tau^2(y_k) per unit length
    top = y > 1.0e-3 - sc.sph.support * dx
    L = sc.domain.bounds_max[0] - sc.domain.bounds_min[0]
    rows = np.unique(np.round((1.0e-3 - y[top]) / dx - 0.5).astype(int))
    H = sc.sph.support * dx
    s_w = kernel_constants(Kernel.WENDLAND_C2, 2, H)[0]
    lateral = np.arange(-40, 41) * dx
    share = np.array([sum(w(int(Kernel.WENDLAND_C2), math.hypot(l, (k + 0.5) * dx), H, s_w) for l in lateral)
                      for k in rows])
    share /= share.sum()
    u_tau2 = np.array([(U / _u_plus_by_bisection((k + 0.5) * dx * U / nu)) ** 2 for k in rows])
    expected = sc.fluid.rest_density * float(share @ u_tau2)
    assert float((m * ax)[top].sum()) / L == pytest.approx(expected, rel=1e-9)
    assert (ax[top] >= 0.0).all() and ax[top].max() > 0.0
    # and the plate at rest leaves the fluid at rest next to it alone, as does the bulk (what is left
    # there is the round-off of the lattice's pressure forces)
    assert np.abs(ax[~top]).max() < 1e-9 * ax[top].max()


def test_a_floating_body_feels_the_reaction_to_its_walls_friction():
    # Given a floating box sliding at 0.3 m/s through water at rest, no gravity: with the walls'
    # friction on, and off (the container's walls see no slip, so only the box's wall rubs)
    sims = {}
    for nu in (0.0, 1.0e-6):
        sc = load_scene(CONFIGS / "floating_box_2d.toml", ["particles.spacing=0.02", "forces.gravity=[0.0, 0.0]",
                                                          "obstacles[0].free=[true, true]", f"terms.wall_friction={nu}"])
        sim = Simulation(sc, "f64")
        sim.model.walls.bodies[0].v = np.array([0.3, 0.0, 0.0])
        sim.step()
        sims[nu] = sim
    off, on = sims[0.0], sims[1.0e-6]
    n = on.state.n_owned
    # When the step has computed the fluid's accelerations and the body's force
    assert np.array_equal(on.state.id[:n], off.state.id[:n])
    pull = (on.state.m[:n, None] * (on.state.a[:n] - off.state.a[:n])).sum(axis=0)  # the friction on the fluid
    body = on.model.walls.bodies[0]
    quantum = body.quantum((0.0, 0.0, 0.0))
    # Then the fluid is pulled along the box's motion and the box is held back by exactly as much
    # (Newton's third law, to the exact sum's unit per row)
    assert pull[0] > 1e3 * n * quantum
    assert np.abs(body.force - off.model.walls.bodies[0].force + pull).max() <= n * quantum
