"""A floating body's force as the surface integral of the fluid's traction (sph.body_force =
"traction", physics/traction.py): the quadrature closes, a uniform pressure gives no force and a
linear one exactly its buoyancy however disordered the particles, a sheared layer pulls a face by
mu gamma per unit area, the moments are a peer-independent sum, and a run gives one process's bits
on two peers and resumed. The settling cylinder it was built for is in docs/VALIDATION.md."""
import math

import numpy as np
import pytest

from sphcore.choices import Kernel
from sphcore.physics import traction
from sphcore.physics.kernels import kernel_constants
from sphcore.scene import SceneError, load_scene

from conftest import CONFIGS
from test_floating import SQUARE, SQUARE_COARSE, _one_two_peers_and_resumed

DX = 0.01
H = 3.0 * DX
S_W = kernel_constants(Kernel.WENDLAND_C2, 2, H)[0]
RHO0 = 1000.0
P_SCALE, V_SCALE = 1.0e5, 10.0


def _lattice(lo, hi, jitter, seed=1):
    """2D particles on a lattice of spacing DX over [lo, hi], each moved by up to ``jitter`` DX."""
    g = np.arange(lo, hi + 1e-9, DX)
    x, y = np.meshgrid(g, g, indexing="ij")
    pts = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    rng = np.random.default_rng(seed)
    pts[:, :2] += rng.uniform(-jitter * DX, jitter * DX, (len(pts), 2))
    return pts


def _force(points_rel, normals, areas, centre, x, v, p, mu=0.0, body_v=(0.0, 0.0, 0.0), rows=None, split=None):
    """(F, T, wet) from particles (x, v, p) of mass rho0 DX^2 at rho0; ``split`` sums the moments of the
    rows in that many interleaved parts, as that many peers would."""
    points = centre + points_rel
    n = len(x)
    m = np.full(n, RHO0 * DX * DX)
    rho = np.full(n, RHO0)
    wall_v = np.tile(np.asarray(body_v, dtype=np.float64), (len(points), 1))
    rows = np.arange(n, dtype=np.int64) if rows is None else rows
    parts = [rows] if not split else [rows[k::split] for k in range(split)]
    total = np.zeros((len(points), traction.MOMENTS), dtype=np.int64)
    for part in parts:
        out = np.zeros_like(total)
        traction.traction_moments(points, wall_v, part, x, v, m, rho, p, int(Kernel.WENDLAND_C2), H, S_W, P_SCALE,
                                  V_SCALE, out)
        total += out
    return traction.traction_from_moments(total, points, normals, areas, np.asarray(centre, dtype=np.float64), 2, H,
                                          P_SCALE, V_SCALE, mu), total


def _circle_fluid(a, jitter):
    x = _lattice(-a - 2 * H, a + 2 * H, jitter)
    return x[np.hypot(x[:, 0], x[:, 1]) > a + 0.3 * DX]


@pytest.mark.fast
@pytest.mark.parametrize("shape, dim", [("sphere", 2), ("sphere", 3), ("box", 2), ("box", 3)])
def test_the_quadrature_closes_and_covers_the_surface(shape, dim):
    R = np.eye(3) if shape == "sphere" else np.array([[0.8, -0.6, 0.0], [0.6, 0.8, 0.0], [0.0, 0.0, 1.0]])
    pts, nrm, area = traction.surface_points(shape, dim, 0.1, (0.2, 0.1, 0.3), R, 0.01)
    want = {("sphere", 2): 2 * math.pi * 0.1, ("sphere", 3): 4 * math.pi * 0.01,
            ("box", 2): 2 * (0.2 + 0.1), ("box", 3): 2 * (0.02 + 0.03 + 0.06)}[(shape, dim)]
    assert area.sum() == pytest.approx(want, rel=1e-12)
    assert np.allclose(np.linalg.norm(nrm, axis=1), 1.0)
    assert np.abs((nrm * area[:, None]).sum(axis=0)).max() < 1e-12 * want   # a closed surface: sum n dS = 0
    # every point lies on the surface (the sphere's radius, the box's faces in its own frame)
    local = pts @ R
    if shape == "sphere":
        assert np.allclose(np.linalg.norm(pts, axis=1), 0.1)
    else:
        half = 0.5 * np.array([0.2, 0.1, 0.3])[:dim]
        assert np.allclose(np.abs(local[:, :dim] / half).max(axis=1), 1.0)
    assert area.max() <= 1.2 * 0.005 ** (dim - 1)   # about two points per spacing along the surface


@pytest.mark.fast
@pytest.mark.parametrize("jitter", [0.0, 0.3])
def test_a_uniform_pressure_gives_no_force_and_a_linear_one_its_buoyancy_however_disordered(jitter):
    a = 0.05
    pts, nrm, area = traction.surface_points("sphere", 2, a, (0, 0, 0), np.eye(3), DX)
    x = _circle_fluid(a, jitter)
    v = np.zeros_like(x)
    (F, _, wet), _ = _force(pts, nrm, area, (0.0, 0.0, 0.0), x, v, np.full(len(x), 2.0e4))
    assert wet == len(pts)
    assert np.abs(F).max() < 1e-9 * 2.0e4 * a     # against a uniform 20 kPa, not a nanonewton per metre
    G = np.array([300.0, -9810.0])                 # p = p0 + G . x: the force is -G pi a^2 (Archimedes)
    p = 2.0e4 + x[:, :2] @ G
    (F, T, _), _ = _force(pts, nrm, area, (0.0, 0.0, 0.0), x, v, p)
    assert F[:2] == pytest.approx(-G * math.pi * a * a, rel=1e-6)
    assert abs(T[2]) < 1e-9 * np.abs(G).max() * a ** 3


@pytest.mark.fast
def test_a_sheared_layer_pulls_the_face_it_slides_on_by_mu_gamma():
    # A 2D box, its top face at y = 0.05 wet by a layer sheared at gamma (u = gamma (y - 0.05), the
    # no-slip wall at rest), the particles disordered, no pressure, kept more than H from the sides
    pts, nrm, area = traction.surface_points("box", 2, 0.0, (0.2, 0.1), np.eye(3), DX)
    x = _lattice(-0.06, 0.06, 0.3)
    x[:, 1] = x[:, 1] - x[:, 1].min() + 0.05 + 0.3 * DX
    x = x[x[:, 1] < 0.05 + 4 * H]
    gamma, mu = 40.0, 2.5
    v = np.zeros_like(x)
    v[:, 0] = gamma * (x[:, 1] - 0.05)
    (F, _, wet), sums = _force(pts, nrm, area, (0.0, 0.0, 0.0), x, v, np.zeros(len(x)), mu=mu)
    # Then every point the fit serves feels mu gamma along x, exactly; no other point is wet
    phi = sums[:, 0] * traction.MOMENT_QUANTUM
    fitted = phi >= traction.FIT_FRACTION
    top = np.isclose(pts[:, 1], 0.05)
    assert fitted.sum() > 15 and np.all(top[phi >= traction.DRY_FRACTION])
    assert F[0] == pytest.approx(mu * gamma * area[fitted].sum(), rel=1e-6)
    assert abs(F[1]) < 1e-9 * mu * gamma * 0.2
    # and turns the box clockwise about its centre: T_z = (r x t)_z = -0.05 F_x on the top face
    _, T, _ = traction.traction_from_moments(sums, pts, nrm, area, np.zeros(3), 2, H, P_SCALE, V_SCALE, mu)
    assert T[2] == pytest.approx(-0.05 * F[0], rel=1e-9)


@pytest.mark.fast
def test_the_moments_are_the_same_integers_however_the_rows_are_split():
    a = 0.05
    pts, nrm, area = traction.surface_points("sphere", 2, a, (0, 0, 0), np.eye(3), DX)
    x = _circle_fluid(a, 0.3)
    rng = np.random.default_rng(3)
    v = rng.normal(0.0, 0.1, x.shape)
    p = rng.uniform(0.0, 1.0e4, len(x))
    (F1, T1, _), m1 = _force(pts, nrm, area, (0.0, 0.0, 0.0), x, v, p, mu=1.0)
    (F3, T3, _), m3 = _force(pts, nrm, area, (0.0, 0.0, 0.0), x, v, p, mu=1.0, split=3)
    assert np.array_equal(m1, m3) and np.array_equal(F1, F3) and np.array_equal(T1, T3)


def _square_traction():
    return load_scene(SQUARE, SQUARE_COARSE + ["sph.body_force='traction'", "sph.pressure_gradient='difference'",
                                               "terms.shifting=2.0"])


def test_a_turning_body_under_traction_gives_the_same_bits_on_two_peers_and_after_a_resume(tmp_path):
    one, cluster, resumed, _ = _one_two_peers_and_resumed(tmp_path, _square_traction(), steps=120)
    body = one.model.walls.bodies[0]
    reference = one.final_arrays()
    for sim in (*cluster.peers, resumed):
        other = sim.model.walls.bodies[0]
        for name in ("x", "v", "R", "w"):
            assert np.array_equal(getattr(other, name), getattr(body, name)), name
    for got in (cluster.final_arrays(), resumed.final_arrays()):
        for key in ("id", "x", "v", "rho"):
            assert np.array_equal(reference[key], got[key]), key
    # (by step 120, t = 0.03 s, the pressure wave of the ramped gravity has reached the body: it pushes and turns it)
    assert body.force[1] > 0.0 and body.torque[2] != 0.0 and body.w[2] != 0.0


@pytest.mark.fast
def test_the_scene_refuses_the_difference_form_with_the_reaction_and_traction_without_it_or_with_wall_friction():
    scene = CONFIGS / "settling_cylinder_closed_2d.toml"
    with pytest.raises(SceneError, match="needs sph.body_force = 'traction'"):
        load_scene(scene, ["sph.pressure_gradient='difference'", "terms.shifting=2.0", "sph.body_force='reaction'"])
    with pytest.raises(SceneError, match=r"terms.wall_friction = 1e-06"):
        load_scene(scene, ["terms.wall_friction=1e-6"])
    with pytest.raises(SceneError, match="needs sph.pressure_gradient = 'difference'"):
        load_scene(scene, ["sph.pressure_gradient='symmetric'"])
    load_scene(scene)  # the case itself: the difference form, shifting and the traction


@pytest.mark.fast
def test_a_body_too_large_for_its_spacing_is_refused_before_its_points_are_made():
    """The points' count is known without placing them (exactly for a circle and a box, within a few
    points for a sphere), and a scene whose body would need more than MAX_SURFACE_POINTS is refused:
    a sphere 5,000 spacings wide took minutes in the Gauss-Legendre nodes before any step."""
    for shape, dim, radius, size, spacing in [("sphere", 2, 0.1, (0, 0, 0), 0.003), ("box", 2, 0.0, (0.2, 0.1), 0.007),
                                              ("box", 3, 0.0, (0.2, 0.1, 0.3), 0.011)]:
        placed = len(traction.surface_points(shape, dim, radius, size, np.eye(3), spacing)[0])
        assert traction.surface_point_count(shape, dim, radius, size, spacing) == placed
    for radius, spacing in [(0.1, 0.01), (0.3, 0.007), (1.0, 0.013)]:
        placed = len(traction.surface_points("sphere", 3, radius, (0, 0, 0), np.eye(3), spacing)[0])
        assert abs(traction.surface_point_count("sphere", 3, radius, (0, 0, 0), spacing) - placed) <= 1e-4 * placed + 4
    scene = CONFIGS / "settling_cylinder_2d.toml"
    with pytest.raises(SceneError, match=r"obstacles\[0\].radius = 0.0025 at particles.spacing = 5e-08 needs about "
                                         r"628,319 points"):
        load_scene(scene, ["particles.spacing=5e-8"])


def test_a_peer_accepts_traction_sums_as_long_as_the_bodys_points_need():
    """Each peer sends the others MOMENTS int64 a surface point every step: the size a peer accepts
    (nodes/peer.message_limit) grows by exactly that, so a large body's sums are not dropped unread."""
    from nodes.peer import message_limit
    from sphcore.solver import Simulation
    scene = CONFIGS / "settling_cylinder_2d.toml"
    traction_sim = Simulation(load_scene(scene))
    reaction_sim = Simulation(load_scene(scene, ["sph.pressure_gradient='symmetric'", "sph.body_force='reaction'"]))
    points = len(traction_sim.model.walls.bodies[0].surface[0])
    assert traction_sim.n_particles == reaction_sim.n_particles and points > 0
    grown = message_limit(traction_sim)("body0", 10) - message_limit(reaction_sim)("body0", 10)
    assert grown == 8 * traction.MOMENTS * points


@pytest.mark.fast
def test_in_3d_a_linear_pressure_gives_a_spheres_buoyancy_and_a_rigid_rotation_no_traction():
    # A sphere of radius 5 spacings in a jittered 3D lattice under p = p0 + G . x: the force is
    # -G 4/3 pi a^3; the fluid turning rigidly with the sphere (no strain) exerts no viscous force
    a, h3 = 0.05, 3.0 * DX
    s_w = kernel_constants(Kernel.WENDLAND_C2, 3, h3)[0]
    pts, nrm, area = traction.surface_points("sphere", 3, a, (0, 0, 0), np.eye(3), DX)
    g = np.arange(-a - 2 * h3, a + 2 * h3 + 1e-9, DX)
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    x += np.random.default_rng(5).uniform(-0.2 * DX, 0.2 * DX, x.shape)
    x = x[np.linalg.norm(x, axis=1) > a + 0.3 * DX]
    G = np.array([200.0, -9810.0, 500.0])
    p = 3.0e4 + x @ G
    omega = np.array([0.0, 0.0, 2.0])
    v = np.cross(omega, x)
    wall_v = np.cross(omega, pts)
    m, rho = np.full(len(x), RHO0 * DX ** 3), np.full(len(x), RHO0)
    out = np.zeros((len(pts), traction.MOMENTS), dtype=np.int64)
    rows = np.arange(len(x), dtype=np.int64)
    traction.traction_moments(pts, wall_v, rows, x, v, m, rho, p, int(Kernel.WENDLAND_C2), h3, s_w, P_SCALE, V_SCALE,
                              out)
    F, T, wet = traction.traction_from_moments(out, pts, nrm, area, np.zeros(3), 3, h3, P_SCALE, V_SCALE, 0.0)
    assert wet == len(pts)
    assert F == pytest.approx(-G * 4.0 / 3.0 * math.pi * a ** 3, rel=1e-6)
    assert np.abs(T).max() < 1e-9 * np.abs(G).max() * a ** 4
    Fv, Tv, _ = traction.traction_from_moments(out, pts, nrm, area, np.zeros(3), 3, h3, 0.0, V_SCALE, 1.0)
    assert np.abs(Fv).max() < 1e-9 and np.abs(Tv).max() < 1e-9   # p_scale 0: the viscous part alone
