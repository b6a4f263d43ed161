"""Floating bodies (sphcore/motion.py FloatingBody, physics/bodies.py): obstacles moved by the fluid's
force and the body forces, summed exactly over peers; their state in checkpoints; Archimedes."""
import json
import math

import numpy as np
import pytest

from launch.validate import run_validate
from nodes.cluster import InProcessCluster
from sphcore import checkpoint
from sphcore.checkpoint import CheckpointError
from sphcore.scene import SceneError, load_scene
from sphcore.solver import Simulation

from conftest import CONFIGS

FLOATING = CONFIGS / "floating_box_2d.toml"
COARSE = ["particles.spacing=0.02", "forces.ramp_time=0.02"]


def _checkpoint(root, sim):
    """Write ``sim``'s checkpoint under ``root``; the path of its manifest."""
    part = checkpoint.write_part(root, sim.step_index, 0, sim)
    checkpoint.commit(root, sim.step_index, checkpoint.sim_info(sim), sim.scene.to_dict(), [part])
    return root / f"step_{sim.step_index:08d}" / "manifest.json"


def _one_two_peers_and_resumed(tmp_path, scene, steps=40):
    """``scene`` run for ``steps`` steps in one process (checkpointed half way), on two in-process
    peers, and resumed from that checkpoint: (one, cluster, resumed, the checkpoint's manifest)."""
    one = Simulation(scene, "f64")
    for _ in range(steps // 2):
        one.step()
    root = tmp_path / "checkpoints"
    manifest = json.loads(_checkpoint(root, one).read_text())
    while one.step_index < steps:
        one.step()
    cluster = InProcessCluster(scene, 2, "f64")
    for _ in range(steps):
        cluster.step()
    resumed = Simulation(scene, "f64")
    checkpoint.restore(resumed, checkpoint.load(root))
    while resumed.step_index < steps:
        resumed.step()
    return one, cluster, resumed, manifest


def test_a_box_of_half_the_waters_density_floats_at_half_its_height(tmp_path, capsys):
    rc = run_validate(["floating_box"], quick=True, out=tmp_path)
    lines = [x.split() for x in capsys.readouterr().out.splitlines() if x.startswith("floating_box.")]
    assert [line[3] for line in lines] == ["PASS", "PASS"] and rc == 0, lines
    assert (tmp_path / "floating_box.png").stat().st_size > 10_000


def test_a_floating_box_gives_the_same_bits_on_two_peers_and_after_a_resume(tmp_path):
    # Given the floating box, 40 steps in one process, checkpointed at step 20; when two peers run
    # it, and the second half is resumed from the checkpoint
    one, cluster, resumed, _ = _one_two_peers_and_resumed(tmp_path, load_scene(FLOATING, COARSE))
    reference, body = one.final_arrays(), one.model.walls.bodies[0]
    # Then the particles and the body end with the one process's bits, and the body moved (it was
    # released 2 cm above where it floats: it sinks first), vertically only, under the fluid's force
    for sim in (*cluster.peers, resumed):
        other = sim.model.walls.bodies[0]
        assert np.array_equal(other.x, body.x) and np.array_equal(other.v, body.v), (other, body)
    for got in (cluster.final_arrays(), resumed.final_arrays()):
        for key in ("id", "x", "v", "rho"):
            assert np.array_equal(reference[key], got[key]), key
    assert body.x[1] < 0.0 and body.x[0] == 0.0 and body.force[1] != 0.0


def test_a_checkpoint_without_the_body_or_with_a_bad_one_is_refused(tmp_path):
    scene = load_scene(FLOATING, COARSE)
    sim = Simulation(scene, "f64")
    sim.step()
    root = tmp_path / "checkpoints"
    manifest = _checkpoint(root, sim)
    good = json.loads(manifest.read_text())
    assert len(good["bodies"]) == 1 and len(good["bodies"][0]) == 9
    for bad, message in (([[0.0] * 8], "bodies = [[0.0, 0.0"), ([[0.0] * 8 + [float("nan")]], "bodies"),
                         ("x", "bodies = \"x\""), ([], "holds 0 floating bodies, its scene has 1")):
        manifest.write_text(json.dumps(dict(good, bodies=bad)))
        with pytest.raises(CheckpointError) as e:
            checkpoint.restore(Simulation(scene, "f64"), checkpoint.load(root))
        assert message in str(e.value), str(e.value)


def test_a_live_change_keeps_the_body_where_it_is():
    scene = load_scene(FLOATING, COARSE)
    sim = Simulation(scene, "f64")
    for _ in range(30):
        sim.step()
    x, v = sim.model.walls.bodies[0].x.copy(), sim.model.walls.bodies[0].v.copy()
    sim.change_scene(load_scene(FLOATING, COARSE + ["terms.xsph=0.1"]))  # a restart in place: a new Model
    body = sim.model.walls.bodies[0]
    assert np.array_equal(body.x, x) and np.array_equal(body.v, v) and np.any(x != 0.0)


@pytest.mark.fast
@pytest.mark.parametrize("lines, message", [
    ('shape = "box"\ndensity = 500.0\nvelocity = [1.0, 0.0]\n', "obstacles[0].density = 500.0: a floating body is moved"),
    ('shape = "box"\ndensity = 500.0\nfree = [false, false]\n', "obstacles[0].free = [False, False]: a floating body needs"),
    ('shape = "box"\ndensity = -1.0\n', "obstacles[0].density"),
    ('shape = "box"\ndensity = 1e-300\n', "obstacles[0].density = 1e-300: below 0.1 x fluid.rest_density"),
    ('shape = "box"\nvelocity = [1e300, 0.0]\n', "the wall moves at up to 1e+300 m/s, not below sph.sound_speed"),
    ('shape = "box"\namplitude = [0.01, 0.0]\nfrequency = 1e300\n', "the wall moves at up to 6.28e+298 m/s"),
    ('shape = "box"\ndensity = 500.0\nfree_rotation = [true, false, false]\n',
     "obstacles[0].free_rotation = [True, False, False]: a 2D body turns about z only"),
    ('shape = "box"\nfree_rotation = [false, false, true]\n',
     "obstacles[0].free_rotation = [False, False, True]: only a floating body turns freely"),
    ('shape = "box"\ndensity = 500.0\nfree_rotation = [false, true]\n', "obstacles[0].free_rotation = [False, True]: "
                                                                       "expected 3 components"),
    ('shape = "box"\ndensity = 500.0\nfree_rotation = "yes"\n', "obstacles[0].free_rotation"),
    ('shape = "box"\ndensity = 500.0\nangular_velocity = [0, 0, 30]\n',
     "a floating body is turned by the fluid, not by prescription"),
])
def test_a_bad_floating_body_is_refused_with_the_key_and_the_value(tmp_path, lines, message):
    text = (CONFIGS / "dam_break_2d.toml").read_text() + '\n[[obstacles]]\ncenter = [0.7, 0.1]\n' + lines
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SceneError) as e:
        load_scene(path)
    assert message in str(e.value)


@pytest.mark.fast
def test_floating_bodies_and_moving_walls_need_the_weakly_compressible_solver():
    with pytest.raises(SceneError, match="floating bodies need sph.solver = 'wcsph'"):
        load_scene(FLOATING, ["sph.solver=dfsph", "time.dt=0.002", "sph.density=summation"])
    with pytest.raises(SceneError, match="moving walls need sph.solver = 'wcsph'"):
        load_scene(CONFIGS / "couette_2d.toml", ["sph.solver=dfsph", "time.integrator=symplectic_euler"])


@pytest.mark.fast
def test_the_viewer_takes_only_well_formed_body_positions_off_the_wire():
    from nodes.walls_view import body_shifts, obstacle_distance
    scene = load_scene(FLOATING)
    shifts = body_shifts(scene, {"0": [0.0, -0.02, 0.0], "1": [0, 0, 0], "x": [1, 2, 3], "0 ": "nan"})
    assert list(shifts) == [0] and np.array_equal(shifts[0][0], [0.0, -0.02, 0.0]) and shifts[0][1] is None
    for bad in (None, [], {"0": [float("nan"), 0, 0]}, {"0": [0, 0]}, {"0": {"a": 1}}, {"-1": [0, 0, 0]}):
        assert body_shifts(scene, bad) == {}
    # the box is drawn where the peers say it is: its bottom face 2 cm lower
    sdf = obstacle_distance(scene)
    bottom = np.array([[0.5, 0.38 - 0.02 - 0.01, 0.0]])  # 1 cm below the displaced bottom face
    assert sdf(bottom, 0.0, shifts)[0] == pytest.approx(0.01, abs=1e-12)


def test_a_body_denser_than_the_fluid_that_sinks_through_the_floor_stops_the_run(tmp_path):
    from sphcore.solver import SimulationError
    text = (CONFIGS / "dam_break_2d.toml").read_text() + (
        '\n[[obstacles]]\nshape = "sphere"\ncenter = [0.1, 0.2]\nradius = 0.05\ndensity = 1e6\n')
    path = tmp_path / "sinking.toml"
    path.write_text(text)
    sim = Simulation(load_scene(path, ["particles.spacing=0.02", "forces.ramp_time=0"]), "f64")
    with pytest.raises(SimulationError) as e:
        for _ in range(5000):
            sim.step()
    assert "floating body obstacles[0] left the domain" in str(e.value) and "not modelled" in str(e.value)


# -- bodies that turn (free_rotation) -------------------------------------------------------------

SQUARE = CONFIGS / "floating_square_2d.toml"
SQUARE_COARSE = ["particles.spacing=0.02", "forces.ramp_time=0.02"]


def test_a_square_log_rolls_over_to_45_degrees_and_passes_its_case(tmp_path, capsys):
    rc = run_validate(["floating_square"], quick=True, out=tmp_path)
    lines = [x.split() for x in capsys.readouterr().out.splitlines() if x.startswith("floating_square.")]
    assert [line[3] for line in lines] == ["PASS", "PASS"] and rc == 0, lines
    assert (tmp_path / "floating_square.png").stat().st_size > 10_000


def test_a_wide_box_tilted_10_degrees_rights_itself_where_the_square_rolls_over():
    # Given the floating box (0.2 m x 0.1 m, half the water's density: metacentric height +4.2 cm,
    # stable flat), tilted 10 degrees and free to turn, released where it floats
    from launch.validate import body_angle
    scene = load_scene(FLOATING, ["particles.spacing=0.02", "forces.ramp_time=0.1", "obstacles[0].center=[0.5, 0.41]",
                                  "obstacles[0].rotation=[0, 0, 10]", "obstacles[0].free_rotation=[false, false, true]"])
    sim = Simulation(scene, "f64")
    body = sim.model.walls.bodies[0]
    angles = []
    while sim.t < 1.5:
        sim.step()
        angles.append(10.0 + body_angle(body))
    # Then the fluid's torque turns it back towards flat (the square, unstable flat, turns away to 45)
    late = np.array(angles[len(angles) // 2:])
    assert min(angles) < 2.0 and np.all(np.abs(late) < 4.0), (min(angles), late.min(), late.max())
    assert body.x[0] == 0.0 and body.R[2, 2] == 1.0  # heave and roll only: no drift along x, no turn out of plane


def test_a_turning_body_gives_the_same_bits_on_two_peers_and_after_a_resume(tmp_path):
    # Given the square log, 40 steps in one process, checkpointed at step 20; when two peers run it
    # (the body straddles their boundary), and the second half is resumed from the checkpoint
    one, cluster, resumed, manifest = _one_two_peers_and_resumed(tmp_path, load_scene(SQUARE, SQUARE_COARSE))
    assert len(manifest["bodies"][0]) == 24  # X, u, a; R, Omega, alpha
    reference, body = one.final_arrays(), one.model.walls.bodies[0]
    # Then the body turned, and every copy of it and of the particles has the one process's bits
    assert body.w[2] != 0.0 and body.torque[2] != 0.0 and body.R[0, 1] != 0.0
    for sim in (*cluster.peers, resumed):
        other = sim.model.walls.bodies[0]
        for name in ("x", "v", "R", "w", "alpha"):
            assert np.array_equal(getattr(other, name), getattr(body, name)), name
    for got in (cluster.final_arrays(), resumed.final_arrays()):
        for key in ("id", "x", "v", "rho"):
            assert np.array_equal(reference[key], got[key]), key


def test_a_checkpoint_with_a_bad_orientation_is_refused_and_nothing_is_restored(tmp_path):
    scene = load_scene(SQUARE, SQUARE_COARSE)
    sim = Simulation(scene, "f64")
    sim.step()
    root = tmp_path / "checkpoints"
    manifest = _checkpoint(root, sim)
    good = json.loads(manifest.read_text())
    state = good["bodies"][0]
    sheared = state[:9] + [1.0, 0.5, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0] + state[18:]
    mirrored = state[:9] + [-1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0] + state[18:]
    for bad, message in (([state[:9]], "bodies[0]: expected 24 numbers for a body that turns, got 9"),
                         ([sheared], "bodies[0]: its orientation (numbers 10-18) is not a rotation matrix"),
                         ([mirrored], "is not a rotation matrix"), ([state + [0.0]], "bodies = ")):
        manifest.write_text(json.dumps(dict(good, bodies=bad)))
        fresh = Simulation(scene, "f64")
        before = fresh.state.x.copy()
        with pytest.raises(CheckpointError) as e:
            checkpoint.restore(fresh, checkpoint.load(root))
        assert message in str(e.value), str(e.value)
        assert fresh.step_index == 0 and np.array_equal(fresh.state.x, before)  # nothing half restored
        assert np.array_equal(fresh.model.walls.bodies[0].R, np.eye(3))


@pytest.mark.fast
def test_a_constant_torque_turns_a_body_as_symplectic_euler_says():
    from sphcore.motion import FloatingBody, inertia_tensor
    # A 2D box (per metre: M = 5 kg/m, 0.2 m x 0.1 m): I_zz = M (a^2 + b^2) / 12
    inertia = inertia_tensor("box", 2, 5.0, (0.2, 0.1))
    assert inertia[2, 2] == pytest.approx(5.0 * 0.05 / 12.0, rel=1e-15)
    body = FloatingBody(wall=0, mass=5.0, free=np.zeros(3), free_rotation=np.array([0.0, 0.0, 1.0]), inertia=inertia)
    dt, torque, n = 1e-3, 0.3, 500
    for _ in range(n):
        body.advance((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), dt, (0.0, 0.0, torque))
    alpha = torque / inertia[2, 2]
    theta = alpha * dt * dt * n * (n + 1) / 2  # Omega_k = k dt alpha, theta = dt sum_k Omega_k
    assert body.w[2] == pytest.approx(n * dt * alpha, rel=1e-12)
    assert math.atan2(body.R[1, 0], body.R[0, 0]) == pytest.approx(theta, rel=1e-9)
    assert np.allclose(body.R @ body.R.T, np.eye(3), atol=1e-13) and np.array_equal(body.x, np.zeros(3))


@pytest.mark.fast
def test_a_torque_free_spinning_body_keeps_its_angular_momentum_and_locked_axes_stay_still():
    from sphcore.motion import FloatingBody, inertia_tensor
    from sphcore.boundaries import rotation_matrix
    # Given a 3D box (M = 6 kg, 0.3 x 0.2 x 0.1 m) placed turned, spinning about an axis that is not
    # a principal one, with no torque: Euler's equations keep L = I Omega in the world's axes
    R0 = rotation_matrix((20.0, -35.0, 50.0))
    inertia = R0 @ inertia_tensor("box", 3, 6.0, (0.3, 0.2, 0.1)) @ R0.T
    body = FloatingBody(wall=0, mass=6.0, free=np.ones(3), free_rotation=np.ones(3), inertia=inertia)
    body.w = np.array([3.0, -1.0, 2.0])
    L0 = inertia @ body.w
    for _ in range(2000):
        body.advance((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 1e-4)
    L = body.R @ inertia @ body.R.T @ body.w
    assert np.linalg.norm(L - L0) < 1e-3 * np.linalg.norm(L0), (L, L0)  # first order in dt: 0.2 s at 1e-4 s
    assert 0.5 * body.w @ L == pytest.approx(0.5 * np.array([3.0, -1.0, 2.0]) @ L0, rel=1e-3)  # its energy too
    assert np.linalg.norm(body.w - [3.0, -1.0, 2.0]) > 0.1  # while Omega wanders (it is not a principal axis)
    assert np.allclose(body.R @ body.R.T, np.eye(3), atol=1e-12)
    # And a body free about z only turns about z only, its alpha_z = T_z / I_zz (the joint takes the rest)
    locked = FloatingBody(wall=0, mass=6.0, free=np.zeros(3), free_rotation=np.array([0.0, 0.0, 1.0]), inertia=inertia)
    locked.advance((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 1e-3, (0.5, -0.7, 0.2))
    assert locked.alpha[0] == 0.0 and locked.alpha[1] == 0.0
    assert locked.alpha[2] == pytest.approx(0.2 / inertia[2, 2], rel=1e-14)


@pytest.mark.fast
def test_the_viewer_draws_a_turned_body_turned_and_refuses_an_orientation_that_is_not_a_rotation():
    from nodes.walls_view import body_shifts, body_transform, obstacle_distance
    scene = load_scene(SQUARE)
    c, s = math.cos(math.radians(40.0)), math.sin(math.radians(40.0))
    R = [c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0]
    shifts = body_shifts(scene, {"0": [0.01, 0.0, 0.0, *R]})
    assert list(shifts) == [0] and np.array_equal(shifts[0][0], [0.01, 0.0, 0.0])
    for bad in ([0.0, 0.0, 0.0, *([2.0] + R[1:])], [0.0] * 12, [0.0, 0.0, 0.0, -1, 0, 0, 0, 1, 0, 0, 0, 1], [0.0] * 11):
        assert body_shifts(scene, {"0": bad}) == {}, bad
    # the square (placed at 5 degrees, turned 40 more) stands on a corner: 0.2 / sqrt(2) m below its centre
    sdf = obstacle_distance(scene)
    corner = np.array([[0.51, 0.5 - 0.1 * math.sqrt(2.0) - 0.01, 0.0]])
    assert sdf(corner, 0.0, shifts)[0] == pytest.approx(0.01, abs=1e-9)
    move = body_transform(scene, 0, *shifts[0])
    centre = np.array([0.5, 0.5, 0.0])
    assert np.allclose(move["mat3x3"] @ centre + move["translation"], centre + [0.01, 0.0, 0.0])  # turns about its centre


def test_a_3d_box_turned_about_three_axes_gives_the_same_bits_on_two_peers():
    # Given a 3D box of half the water's density, placed turned about x, y and z in the dam break's
    # water column and free to turn about every axis
    scene = load_scene(CONFIGS / "obstacle.toml", [
        "particles.spacing=0.03", "time.dt=0.001", 'obstacles[0].shape="box"', "obstacles[0].size=[0.12, 0.12, 0.12]",
        "obstacles[0].rotation=[10, 20, 5]", "obstacles[0].center=[-0.42, 0.0, 0.0]", "obstacles[0].density=500",
        "obstacles[0].free_rotation=[true, true, true]"])
    one, cluster = Simulation(scene, "f64"), InProcessCluster(scene, 2, "f64")
    for _ in range(60):
        one.step()
        cluster.step()
    # Then the fluid turned it about all three axes, alike on both peers and in one process
    body = one.model.walls.bodies[0]
    assert np.all(body.w != 0.0) and np.all(body.torque != 0.0), body.w
    for peer in cluster.peers:
        other = peer.model.walls.bodies[0]
        assert np.array_equal(other.R, body.R) and np.array_equal(other.x, body.x)
    reference, got = one.final_arrays(), cluster.final_arrays()
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(reference[key], got[key]), key
