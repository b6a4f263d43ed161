"""Inlets and outlets ([[inlets]], [[outlets]]; sphcore/open_boundary.py, physics/open_boundary.py):
the scene's checks, the inlet's lattice (layers, ids and positions from the time alone), N peers ==
one process bit for bit while particles enter and leave, a resumed run == the continuous one, the
wire's id check, and the developing channel flow against plane Poiseuille (`sph validate channel`)."""
import re
import subprocess
import sys

import numpy as np
import pytest

from launch.validate import CaseOptions, channel
from nodes.cluster import InProcessCluster
from nodes.driver import RunPlan
from sphcore import checkpoint
from sphcore.open_boundary import ID_STRIDE
from sphcore.scene import SceneError, load_scene
from sphcore.solver import Simulation

from conftest import CONFIGS
from test_steering import run_one

CHANNEL = CONFIGS / "channel_2d.toml"
ROOT = CONFIGS.parent


# -- the scene's checks ----------------------------------------------------------------------------
BAD = [
    (["inlets[0].velocity=[0.01, 0.01]"], "inlets[0].velocity = [0.01, 0.01]: must lie along one axis"),
    (["inlets[0].velocity=[0.0, 0.0]"], "inlets[0].velocity = [0.0, 0.0]: must lie along one axis"),
    (["inlets[0].max=[1e-3, 1e-2]"], "inlets[0]: 0.001 m thick along x, less than the support radius"),
    (["inlets[0].max=[-1e-3, 1e-2]"], "inlets[0].max = [-0.001, 0.01]: must exceed inlets[0].min"),
    (["inlets[0].velocity=[0.05, 0.0]"], "at least 0.1 x sph.sound_speed = 0.02 m/s"),
    (["outlets[0].direction=[2.0, 0.0]"], "outlets[0].direction = [2.0, 0.0]: must be a unit vector"),
    (["outlets[0].min=[2e-3, 0.0]", "outlets[0].max=[6e-3, 1e-2]"], "outlets[0]: overlaps inlets[0]"),
    (["sph.solver='dfsph'", "time.integrator='symplectic_euler'"], "inlets and outlets need sph.solver = 'wcsph'"),
    (["inlets[0].min=[0.0, 0.0, 0.1]"], "inlets[0]: min and max z must be 0 in a 2D scene"),
    (["inlets[0].max=[3e-3, 1e6]"], "inlets[0]: the zone [0.0, 0.0] .. [0.003, 1000000.0] reaches outside the domain's "
     "box [0.0, 0.0] .. [0.06, 0.01]"),
    # an outlet pointing in or placed mid-channel removed the fluid, an inlet mid-channel compressed it
    (["outlets[0].direction=[-1.0, 0.0]"], "outlets[0]: its downstream face (x = 0.057 m, from outlets[0].direction = "
     "[-1.0, 0.0]) must lie on the domain's edge at x = 0 m"),
    (["outlets[0].min=[0.03, 0.0]", "outlets[0].max=[0.033, 0.01]"], "outlets[0]: its downstream face (x = 0.033 m"),
    (["inlets[0].min=[0.03, 0.0]", "inlets[0].max=[0.033, 0.01]"], "inlets[0]: its upstream face (x = 0.03 m"),
    (["inlets[0].velocity=[-0.01, 0.0]"], "inlets[0]: its upstream face (x = 0.003 m"),
    (["inlets[0].velocity=[0.0, 0.01]"], "inlets[0]: its upstream face at y = 0 m is a wall or a periodic edge"),
]


@pytest.mark.fast
@pytest.mark.parametrize("overrides,message", BAD, ids=[b[1][:40] for b in BAD])
def test_a_bad_zone_is_refused_naming_the_key(overrides, message):
    with pytest.raises(SceneError, match=re.escape(message)):
        load_scene(CHANNEL, overrides)


@pytest.mark.fast
def test_a_zone_needs_its_corners(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(CHANNEL.read_text() + "\n[[outlets]]\nmin = [0.02, 0.0]\n")
    with pytest.raises(SceneError, match=r"outlets\[1\]: no max given"):
        load_scene(path)


@pytest.mark.fast
def test_an_inlet_with_no_node_off_the_walls_is_refused_before_the_first_step(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(CHANNEL.read_text() + '\n[[domain.planes]]\npoint = [0.0, 0.0]\nnormal = [1.0, 0.0]\n')
    with pytest.raises(SceneError, match=r"inlets\[0\]: no node of its cross-section lies inside the domain"):
        Simulation(load_scene(path, ["domain.planes[2].point=[0.01, 0.0]", "fluid.blocks[0].clip=true"]), "f64")


@pytest.mark.fast
def test_zones_cannot_change_during_a_run():
    sim = Simulation(load_scene(CHANNEL), "f64")
    with pytest.raises(ValueError, match="inlets.*cannot change during a run: it creates or removes particles"):
        sim.set_parameter("inlets[0].velocity", (0.02, 0.0, 0.0))


# -- the inlet's lattice ---------------------------------------------------------------------------
@pytest.mark.fast
def test_the_inlet_fills_itself_and_its_layers_follow_from_the_time():
    sim = Simulation(load_scene(CHANNEL), "f64")
    lat, op = sim.open.inlets[0], sim.open
    dx, U = lat.dx, lat.U
    # 20 nodes across the 1 cm channel, 6 layers in its 3 mm zone; the blocks' rows in it are replaced
    assert len(lat.nodes) == 20 and lat.K0 == 6
    assert op.n_initial == 120 * 20 - 6 * 20 and sim.n_particles == 120 * 20
    s = sim.state
    inlet = s.id >= ID_STRIDE
    assert inlet.sum() == 120 and np.all(s.x[inlet, 0] < 3e-3) and np.all(s.x[~inlet, 0] >= 3e-3)
    # a layer k appears once U t >= (k - K0 + 1/2) dx, at its place in the moving lattice
    assert [lat.layers(t) for t in (0.0, 0.49 * dx / U, 0.51 * dx / U, 1.51 * dx / U)] == [6, 6, 7, 8]
    ids, x, v = lat.rows(6, 8, 1.51 * dx / U)
    assert np.array_equal(ids, ID_STRIDE + np.arange(120, 160))
    assert np.allclose(x[:20, 0], 1.01 * dx) and np.allclose(x[20:, 0], 0.01 * dx)  # xi_6 and xi_7
    assert np.all(v[:, 0] == U)
    # which ids can exist: the blocks', and the inlet's made by now
    assert sim.ids_valid(np.array([0, op.n_initial - 1, ID_STRIDE + 119]))
    for bad in (op.n_initial, ID_STRIDE + 120, -1, 2 * ID_STRIDE):
        assert not sim.ids_valid(np.array([bad])), bad


def test_the_inlets_rows_move_at_its_velocity_and_the_outlet_removes_what_passes_it():
    sim = Simulation(load_scene(CHANNEL), "f64")
    for _ in range(300):
        sim.step()
    s, lat = sim.state, sim.open.inlets[0]
    n = s.n_owned
    x, v = s.x[:n], s.v[:n]
    inside = x[:, 0] < 3e-3
    assert np.all(v[inside, 0] == lat.U) and np.all(v[inside, 1] == 0.0)
    assert np.all(x[:, 0] < 6e-2)  # nothing past the outlet's far face
    made = sim.open.created(sim.t) - sim.open.created(0.0)
    assert sim.open.inflow == made > 0 and sim.open.outflow > 0
    assert sim.n_particles == n == 2400 + sim.open.inflow - sim.open.outflow
    assert len(np.unique(s.id[:n])) == n


# -- N peers, resume, the wire ---------------------------------------------------------------------
@pytest.mark.fast
def test_two_and_three_peers_run_the_channel_as_one_process_bit_for_bit(tmp_path):
    sc = load_scene(CHANNEL)
    final = {}
    for peers in (1, 2, 3):
        dims = {"dims": (peers, 1, 1)} if peers > 1 else {}
        summary = InProcessCluster(sc, peers, "f64", **dims).run(RunPlan(400, out=tmp_path / str(peers),
                                                                         progress=False))
        final[peers] = dict(np.load(tmp_path / str(peers) / "final.npz"))
        assert summary["open_boundaries"]["added"] > 0 and summary["open_boundaries"]["removed"] > 0
        assert summary["particles"] == len(final[peers]["id"])
    for peers in (2, 3):
        for k in ("id", "x", "v", "rho"):
            assert np.array_equal(final[1][k], final[peers][k]), (peers, k)


@pytest.mark.fast
def test_a_resumed_channel_run_equals_the_continuous_one(tmp_path):
    sc = load_scene(CHANNEL)
    whole, _, _ = run_one(sc, tmp_path / "whole", 300)
    run_one(sc, tmp_path / "part", 150, checkpoint_every=150)
    ckpt = checkpoint.load(tmp_path / "part" / "checkpoints")
    resumed, _, _ = run_one(sc, tmp_path / "part", 300, resume=ckpt)
    assert resumed["open_boundaries"] == whole["open_boundaries"] and resumed["particles"] == whole["particles"]
    a, b = (dict(np.load(tmp_path / d / "final.npz")) for d in ("whole", "part"))
    for k in ("id", "x", "v", "rho"):
        assert np.array_equal(a[k], b[k]), k
    # a checkpoint whose ids its scene cannot make by its time is refused
    ckpt = checkpoint.load(tmp_path / "part" / "checkpoints")
    ckpt.arrays["id"][-1] = ID_STRIDE + 10**6
    with pytest.raises(checkpoint.CheckpointError, match="ids are not those its scene's blocks and inlets make"):
        checkpoint.restore(Simulation(sc, "f64"), ckpt)


def test_two_peer_processes_over_zenoh_run_the_channel_as_one_process(tmp_path):
    """Real peers: the wire's checks accept the inlet's new ids, and the result is one process's."""
    common = ["--steps", "200", "--precision", "f64", "--no-viewer", "--quiet"]
    for name, extra in (("one", []), ("two", ["--peers", "2"])):
        done = subprocess.run([sys.executable, "-m", "launch.cli", "run", str(CHANNEL), *common, *extra, "--out",
                               str(tmp_path / name)], cwd=ROOT, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr[-3000:]
    a, b = (dict(np.load(tmp_path / d / "final.npz")) for d in ("one", "two"))
    for k in ("id", "x", "v", "rho"):
        assert np.array_equal(a[k], b[k]), k


# -- validation ------------------------------------------------------------------------------------
def test_the_developing_channel_flow_reaches_plane_poiseuille(tmp_path):
    metrics = channel(True, tmp_path, opts=CaseOptions(plot=False))
    assert [m.name for m in metrics] == ["channel.profile_rms_of_u_max", "channel.flux_error_of_U_D",
                                         "channel.outflow_minus_inflow"]
    for m in metrics:
        assert m.passed, m.line()


def test_the_recording_draws_the_zones_in_the_3d_view(tmp_path):
    from launch.cli import main
    from nodes.recording import blueprint, entity_steps
    assert main(["run", str(CHANNEL), "--steps", "20", "--set", "render.every=10", "--quiet", "--out",
                 str(tmp_path)]) == 0
    rrd = tmp_path / "run.rrd"
    entities = entity_steps(rrd)
    assert "/inlets/0" in entities and "/outlets/0" in entities
    view = next(v for v in blueprint(rrd)["views"] if v["kind"] == "3D")
    assert "/inlets/**" in view["contents"] and "/outlets/**" in view["contents"]
