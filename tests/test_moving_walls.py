"""Moving walls (sphcore/motion.py): planes and obstacles translated as functions of time, the wall's
velocity in the no-slip drag and the collision guard, its acceleration in the pressure behind it;
every peer moves them to the same bits, a resumed run to its checkpoint's time."""
import math

import numpy as np
import pytest

from launch.validate import couette_velocity, run_validate
from nodes.cluster import InProcessCluster
from sphcore import checkpoint
from sphcore.motion import Motion
from sphcore.scene import SceneError, load_scene
from sphcore.solver import Simulation, _same
from sphcore.state import ParticleState

from conftest import CONFIGS

# The 2D dam break, coarse, with a sphere that moves through the column to the right while it bobs
MOVING_SPHERE = """
[[obstacles]]
shape = "sphere"
center = [0.1, 0.2]
radius = 0.05
velocity = [2.0, 0.0]
amplitude = [0.0, 0.03]
frequency = 4.0
phase = 30.0
"""


def moving_sphere_scene(tmp_path, extra=""):
    text = (CONFIGS / "dam_break_2d.toml").read_text() + MOVING_SPHERE + extra
    path = tmp_path / "moving_sphere.toml"
    path.write_text(text)
    return load_scene(path, ["particles.spacing=0.02", "run.energy_check_every=100"])


@pytest.mark.fast
def test_the_displacement_starts_at_zero_and_its_derivatives_are_the_velocity_and_acceleration():
    class Item:
        velocity, amplitude, frequency, phase = (0.3, -0.1, 0.0), (0.02, 0.05, 0.0), 1.7, 40.0
    m = Motion.of(Item)
    assert np.array_equal(m.displacement(0.0), np.zeros(3))
    h = 1e-6
    for t in (0.0, 0.13, 0.9):
        dv = (m.displacement(t + h) - m.displacement(t - h)) / (2 * h)
        da = (m.wall_velocity(t + h) - m.wall_velocity(t - h)) / (2 * h)
        assert np.allclose(dv, m.wall_velocity(t), rtol=0, atol=1e-8)
        assert np.allclose(da, m.wall_acceleration(t), rtol=0, atol=1e-6)

    class Still:
        velocity, amplitude, frequency, phase = (0.0, 0.0), (0.0, 0.0), 0.0, 0.0
    assert Motion.of(Still) is None


@pytest.mark.fast
def test_a_path_passes_through_its_rows_smoothly_and_rests_outside_them():
    from sphcore.motion import Path

    class Item:
        velocity, amplitude, frequency, phase = (0.0, 0.0), (0.0, 0.0), 0.0, 0.0
        path = ((0.0, 0.0, 0.0), (0.5, 0.1, 0.0), (1.0, 0.1, 0.05), (2.0, -0.1, 0.0))
    m = Motion.of(Item)
    assert isinstance(m, Path)
    # it passes through every row, and rests before the first and after the last
    for t, x, y in Item.path:
        assert np.array_equal(m.displacement(t)[:2], [x, y])
    assert np.array_equal(m.displacement(-1.0), np.zeros(3)) and np.array_equal(m.displacement(9.0), [-0.1, 0, 0])
    assert not m.wall_velocity(-1.0).any() and not m.wall_velocity(9.0).any() and not m.wall_acceleration(9.0).any()
    # its velocity and acceleration are its derivatives (off the rows), the velocity continuous at them
    h = 1e-6
    for t in (0.1, 0.37, 0.8, 1.5, 1.999):
        dv = (m.displacement(t + h) - m.displacement(t - h)) / (2 * h)
        da = (m.wall_velocity(t + h) - m.wall_velocity(t - h)) / (2 * h)
        assert np.allclose(dv, m.wall_velocity(t), rtol=0, atol=1e-8)
        assert np.allclose(da, m.wall_acceleration(t), rtol=0, atol=1e-5)
    for t, *_ in Item.path:
        assert np.allclose(m.wall_velocity(t - 1e-9), m.wall_velocity(t + 1e-9), rtol=0, atol=1e-6)
    # it never leaves the table's range between rows (monotone), and the speed bound holds
    ts = np.linspace(0.0, 2.0, 20001)
    X = np.array([m.displacement(t) for t in ts])
    assert X[:, 0].max() <= 0.1 + 1e-15 and X[:, 0].min() >= -0.1 - 1e-15 and X[:, 1].min() >= -1e-15
    speed = max(np.linalg.norm(m.wall_velocity(t)) for t in ts)
    assert speed <= m.largest_speed() <= 1.5 * speed


@pytest.mark.fast
def test_a_sphere_on_a_path_follows_it_with_the_same_bits_on_two_peers(tmp_path):
    # Given the dam break with a sphere moved by a table (no velocity or oscillation keys)
    text = (CONFIGS / "dam_break_2d.toml").read_text() + """
[[obstacles]]
shape = "sphere"
center = [0.1, 0.2]
radius = 0.05
path = [[0.0, 0.0, 0.0], [0.002, 0.002, 0.001], [0.004, 0.006, 0.0]]
"""
    path = tmp_path / "path.toml"
    path.write_text(text)
    scene = load_scene(path, ["particles.spacing=0.02"])
    # When it runs 40 steps in one process and on two peers
    one = Simulation(scene, "f64")
    for _ in range(40):
        one.step()
    cluster = InProcessCluster(scene, 2, "f64")
    for _ in range(40):
        cluster.step()
    # Then the sphere is where the path puts it at the walls' time, and both runs have the same bits
    w = one.model.walls
    q = len(w.kind) - 1
    motion = Motion.of(scene.obstacles[0])
    assert np.allclose(w.data[q, :2], np.array([0.1, 0.2]) + motion.displacement(w.t)[:2], rtol=0, atol=1e-15)
    assert w.t == one.t and 0.002 < one.t
    reference, got = one.final_arrays(), cluster.final_arrays()
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(reference[key], got[key]), key


@pytest.mark.fast
def test_walls_move_to_a_time_and_stay_the_same_walls(tmp_path):
    # Given the dam break with a moving sphere
    sim = Simulation(moving_sphere_scene(tmp_path), "f64")
    w = sim.model.walls
    q = len(w.kind) - 1  # the obstacle is the last wall
    container = w.data[: w.container_walls].copy()
    before = Simulation(moving_sphere_scene(tmp_path), "f64").model.walls
    # When the walls are moved to t = 0.3 s
    assert w.at(0.3)
    # Then the sphere's centre is displaced by X(t), its velocity and acceleration are u_w(t), a_w(t)
    m = dict(w.moves)[q]
    assert np.allclose(w.data[q, 0:3], np.array([0.1, 0.2, 0.0]) + m.displacement(0.3), rtol=0, atol=1e-15)
    x_t = 2.0 * 0.3
    y_t = 0.03 * (math.sin(2 * math.pi * 4.0 * 0.3 + math.radians(30.0)) - math.sin(math.radians(30.0)))
    assert np.allclose(w.data[q, 0:2] - [0.1, 0.2], [x_t, y_t], rtol=0, atol=1e-15)
    assert np.allclose(w.motion[q, 0:3], m.wall_velocity(0.3)) and np.allclose(w.motion[q, 3:6], m.wall_acceleration(0.3))
    # ... the container's walls did not move, and the walls are still the scene's walls (a live change
    # compares their definition, not where they are now)
    assert np.array_equal(w.data[: w.container_walls], container)
    assert not np.any(w.motion[: w.container_walls])
    assert _same(w, before)


@pytest.mark.fast
@pytest.mark.parametrize("extra, message", [
    ("amplitude = [0.0, 0.03]\n", "obstacles[0].amplitude = [0.0, 0.03]: an oscillation needs obstacles[0].frequency > 0"),
    ("frequency = 2.0\n", "obstacles[0].frequency = 2.0: an oscillation needs a non-zero obstacles[0].amplitude"),
    ("velocity = [1.0, 0.0, 0.5]\n", "obstacles[0].velocity = [1.0, 0.0, 0.5]: z must be 0 in 2D"),
    ("frequency = -1.0\n", "obstacles[0].frequency"),
    ("path = [[0.0, 0.0, 0.0], [1.0, 0.1, 0.0]]\nvelocity = [1.0, 0.0]\n",
     "obstacles[0].path: give a wall either a path or velocity / amplitude / frequency, not both"),
    ("path = [[0.0, 0.0, 0.0]]\n", "obstacles[0].path = [[0.0, 0.0, 0.0]]: a path needs at least 2 rows"),
    ("path = [[0.0, 0.0, 0.0], [1.0, 0.1]]\n", "obstacles[0].path[1] = [1.0, 0.1]: expected 3 numbers, [t, x, y]"),
    ("path = [[0.0, 0.0, 0.0], [1.0, 0.1, 0.0], [1.0, 0.2, 0.0]]\n",
     "obstacles[0].path[2] = [1.0, 0.2, 0.0]: times must increase (the row before is at t = 1 s)"),
    ("path = [[0.0, 0.1, 0.0], [1.0, 0.2, 0.0]]\n", "obstacles[0].path[0] = [0.0, 0.1, 0.0]: the first row's displacement"
     " must be 0"),
    ("path = [[-1.0, 0.0, 0.0], [1.0, 0.2, 0.0]]\n", "obstacles[0].path[0] = [-1.0, 0.0, 0.0]: the first time must be >= 0"),
    ("path = [[0.0, 0.0, 0.0], [1.0, 'far', 0.0]]\n", "obstacles[0].path[1] = [1.0, 'far', 0.0]: expected a row of "
     "finite numbers"),
    ("path = [[0.0, 0.0, 0.0], [1.0e-6, 1.0, 0.0]]\n", "obstacles[0].path: the wall moves at up to"),
    ("path = [[0.0, 0.0, 0.0], [1.0, 0.1, 0.0]]\ndensity = 500.0\n", "a floating body is moved by the fluid; give it "
     "no obstacles[0].velocity, obstacles[0].amplitude or obstacles[0].path"),
])
def test_a_bad_motion_is_refused_with_the_key_and_the_value(tmp_path, extra, message):
    text = (CONFIGS / "dam_break_2d.toml").read_text() + '[[obstacles]]\nshape = "sphere"\ncenter = [0.7, 0.1]\n' + extra
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SceneError) as e:
        load_scene(path)
    assert message in str(e.value)


@pytest.mark.fast
def test_a_plate_sliding_along_itself_drags_only_the_fluid_within_a_support_of_it():
    # Given the Couette channel at rest, its upper plate sliding at U
    scene = load_scene(CONFIGS / "couette_2d.toml", ["particles.spacing=5e-5"])
    U = scene.domain.planes[1].velocity[0]
    sim = Simulation(scene, "f64")
    # When the accelerations are computed at t = 0
    sim.refresh()
    s = sim.state
    n = s.n_owned
    near_top = 1e-3 - s.x[:n, 1] + 0.5 * 5e-5 < sim.H
    # Then the fluid near the upper plate is pulled along +x, nothing else moves
    assert np.all(s.a[:n][near_top, 0] > 0.0)
    assert np.max(np.abs(s.a[:n][~near_top, 0])) < 1e-9 * np.max(s.a[:n][near_top, 0])
    assert np.max(np.abs(s.a[:n, 1])) < 1e-9 * np.max(s.a[:n][near_top, 0])
    # ... and fluid already moving with the plate (and at rest at the fixed plate: the steady profile)
    # is not dragged at all near the moving plate
    v = np.zeros_like(s.v)
    v[:, 0] = U
    sim.state = ParticleState.create(s.id, s.x, v, s.m, np.float64)
    sim.refresh()
    s = sim.state
    near_top = 1e-3 - s.x[:n, 1] + 0.5 * 5e-5 < sim.H
    near_bottom = s.x[:n, 1] + 0.5 * 5e-5 < sim.H
    assert np.max(np.abs(s.a[:n][near_top & ~near_bottom, 0])) < 1e-12 * U / 1e-4


def test_couette_start_up_flow_meets_its_tolerance(tmp_path, capsys):
    # the series solution starts at rest and ends linear
    y = np.linspace(0.0, 1e-3, 11)
    assert np.max(np.abs(couette_velocity(y[1:-1], 0.0, 2.5e-5, 1e-6, 1e-3, terms=5000))) < 2e-3 * 2.5e-5  # sine series: slow by the plate
    assert np.allclose(couette_velocity(y, 50.0, 2.5e-5, 1e-6, 1e-3), 2.5e-5 * y / 1e-3, rtol=0, atol=1e-15)
    # the quick case: 20 particles across, five profiles to t = 1 s, within 2 % of U
    rc = run_validate(["couette"], quick=True, out=tmp_path)
    line = [x.split() for x in capsys.readouterr().out.splitlines() if x.startswith("couette.")][0]
    assert line[3] == "PASS" and rc == 0, line
    assert (tmp_path / "couette.png").stat().st_size > 10_000


def test_a_moving_sphere_gives_the_same_bits_on_two_peers_and_after_a_resume(tmp_path):
    # Given the dam break with a sphere crossing the tank, run 40 steps in one process
    scene = moving_sphere_scene(tmp_path)
    one = Simulation(scene, "f64")
    for _ in range(20):
        one.step()
    root = tmp_path / "checkpoints"
    part = checkpoint.write_part(root, one.step_index, 0, one)
    checkpoint.commit(root, one.step_index, checkpoint.sim_info(one), one.scene.to_dict(), [part])
    for _ in range(20):
        one.step()
    reference = one.final_arrays()
    # When the same run goes on two peers, and the first half is resumed from its checkpoint
    cluster = InProcessCluster(scene, 2, "f64")
    for _ in range(40):
        cluster.step()
    resumed = Simulation(scene, "f64")
    checkpoint.restore(resumed, checkpoint.load(root))
    while resumed.step_index < 40:
        resumed.step()
    # Then both end with the one process's bits
    for got in (cluster.final_arrays(), resumed.final_arrays()):
        for key in ("id", "x", "v", "rho"):
            assert np.array_equal(reference[key], got[key]), key
    # ... the sphere moved 2 m/s x t to the right and pushed the fluid out of its way: no particle inside
    # it, none leaked; the energy watchdog says why it does not judge this scene
    w = one.model.walls
    q = len(w.kind) - 1
    assert w.data[q, 0] == pytest.approx(0.1 + 2.0 * w.t, abs=1e-12) and w.t == one.t
    r = np.hypot(reference["x"][:, 0] - w.data[q, 0], reference["x"][:, 1] - w.data[q, 1])
    assert r.min() >= 0.05 and one.leaks == 0
    assert one.health.energy["watchdog"].startswith("off: moving walls do work")
    moved = np.linalg.norm(reference["v"], axis=1) > 0.5  # the dam break alone: g t ~ 0.15 m/s by now
    assert np.any(moved & (r < 0.05 + 2 * one.H))  # the fluid around the sphere was set in motion


@pytest.mark.fast
def test_the_viewer_draws_a_moving_obstacle_where_it_is_now(tmp_path):
    # Given the moving sphere's scene, as the viewer sees it
    from nodes.walls_view import moving_obstacles, obstacle_distance
    scene = moving_sphere_scene(tmp_path)
    motion = moving_obstacles(scene)[0]
    sdf = obstacle_distance(scene)
    # When its distance function is evaluated at t = 0 and t = 0.2 s
    for t in (0.0, 0.2):
        centre = np.array([0.1, 0.2, 0.0]) + motion.displacement(t)
        # Then the sphere is centred where the simulation moved it
        assert sdf(centre[None], t)[0] == pytest.approx(-0.05, abs=1e-12)
        assert sdf((centre + [0.05, 0.0, 0.0])[None], t)[0] == pytest.approx(0.0, abs=1e-12)
    assert sdf(np.array([[0.1, 0.2, 0.0]]), 0.2)[0] > 0.3  # it has left its starting place


@pytest.mark.fast
def test_the_composite_shows_a_moving_obstacle_where_it_is_now(tmp_path):
    # Given the moving sphere's scene and its camera
    from nodes.walls_view import obstacle_layer
    from sphcore.render import SceneRenderer
    scene = moving_sphere_scene(tmp_path)
    sim = Simulation(scene, "f64")
    r = SceneRenderer(scene, sim.walls.lo, sim.walls.hi)
    # When the obstacle layer is traced at t = 0 and t = 0.2 s
    hit = [np.isfinite(obstacle_layer(scene, r.camera, r.box, t=t)[1]) for t in (0.0, 0.2)]
    # Then the sphere is drawn in both, X(0.2) = 0.4 m further right in the second (its 0.1 m
    # diameter in pixels gives the image's scale)
    cols = [np.nonzero(h.any(axis=0))[0] for h in hit]
    assert all(len(c) > 3 for c in cols)
    pixels_per_m = len(cols[0]) / 0.1
    assert (cols[1].mean() - cols[0].mean()) / pixels_per_m == pytest.approx(0.4, rel=0.1)
