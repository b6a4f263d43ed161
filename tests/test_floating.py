"""Floating bodies (sphcore/motion.py FloatingBody, physics/bodies.py): obstacles moved by the fluid's
force and the body forces, summed exactly over peers; their state in checkpoints; Archimedes."""
import json

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


def test_a_box_of_half_the_waters_density_floats_at_half_its_height(tmp_path, capsys):
    rc = run_validate(["floating_box"], quick=True, out=tmp_path)
    lines = [x.split() for x in capsys.readouterr().out.splitlines() if x.startswith("floating_box.")]
    assert [line[3] for line in lines] == ["PASS", "PASS"] and rc == 0, lines
    assert (tmp_path / "floating_box.png").stat().st_size > 10_000


def test_a_floating_box_gives_the_same_bits_on_two_peers_and_after_a_resume(tmp_path):
    # Given the floating box, 40 steps in one process, checkpointed at step 20
    scene = load_scene(FLOATING, COARSE)
    one = Simulation(scene, "f64")
    for _ in range(20):
        one.step()
    root = tmp_path / "checkpoints"
    part = checkpoint.write_part(root, one.step_index, 0, one)
    checkpoint.commit(root, one.step_index, checkpoint.sim_info(one), one.scene.to_dict(), [part])
    for _ in range(20):
        one.step()
    reference, body = one.final_arrays(), one.model.walls.bodies[0]
    # When two peers run it, and the second half is resumed from the checkpoint
    cluster = InProcessCluster(scene, 2, "f64")
    for _ in range(40):
        cluster.step()
    resumed = Simulation(scene, "f64")
    checkpoint.restore(resumed, checkpoint.load(root))
    while resumed.step_index < 40:
        resumed.step()
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
    part = checkpoint.write_part(root, sim.step_index, 0, sim)
    checkpoint.commit(root, sim.step_index, checkpoint.sim_info(sim), sim.scene.to_dict(), [part])
    manifest = next(root.glob("step_*")) / "manifest.json"
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
    assert list(shifts) == [0] and np.array_equal(shifts[0], [0.0, -0.02, 0.0])
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
