"""Damping zones ([[damping_zones]], physics/damping.py): the scene's checks, k(x) = rate s^2 across
a zone, a zone that takes a sloshing tank's energy, N peers == one process bit for bit, and the
recording's box. CUDA == CPU: tests/cuda_parity.py "damping_f64"."""
import re

import numpy as np
import pytest

from nodes.cluster import InProcessCluster
from nodes.driver import RunPlan
from sphcore.boundaries import damping_rows
from sphcore.physics.damping import damping_row
from sphcore.scene import SceneError, load_scene
from sphcore.solver import Simulation

from conftest import CONFIGS

WAVES = CONFIGS / "wave_maker_2d.toml"
DAM = CONFIGS / "dam_break_2d.toml"

ZONE = "\n[[damping_zones]]\nmin = [{lo}]\nmax = [{hi}]\ndirection = [{e}]\nrate = {rate}\n"


def with_zone(tmp_path, base=DAM, lo="0.0, 0.0", hi="1.6, 0.6", e="1.0, 0.0", rate=50.0, extra=""):
    path = tmp_path / "scene.toml"
    path.write_text(base.read_text() + ZONE.format(lo=lo, hi=hi, e=e, rate=rate) + extra)
    return path


# -- the scene's checks ----------------------------------------------------------------------------
BAD = [
    ({"e": "1.0, 1.0"}, "damping_zones[0].direction = [1.0, 1.0]: must lie along one axis"),
    ({"e": "0.5, 0.0"}, "damping_zones[0].direction = [0.5, 0.0]: must be a unit vector along one axis"),
    ({"hi": "-0.1, 0.6"}, "damping_zones[0].max = [-0.1, 0.6]: must exceed damping_zones[0].min = [0.0, 0.0]"),
    ({"hi": "1.6, 7.0"}, "damping_zones[0]: the zone [0.0, 0.0] .. [1.6, 7.0] reaches outside the domain's box"),
    ({"rate": 0.0}, "damping_zones[0].rate = 0.0"),
    ({"rate": -3.0}, "damping_zones[0].rate = -3.0"),
    ({"rate": 4000.0}, "damping_zones[0].rate = 4000.0: rate x time.dt = 2 must be below 1"),
    ({"lo": "0.0, 0.0, 0.1", "hi": "1.6, 0.6, 0.2", "e": "1.0, 0.0, 0.0"},
     "damping_zones[0]: min and max z must be 0 in a 2D scene"),
]


@pytest.mark.fast
@pytest.mark.parametrize("zone,message", BAD, ids=[b[1][:50] for b in BAD])
def test_a_bad_damping_zone_is_refused_naming_the_key(tmp_path, zone, message):
    with pytest.raises(SceneError, match=re.escape(message)):
        load_scene(with_zone(tmp_path, **zone))


@pytest.mark.fast
def test_a_damping_zone_needs_its_keys(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(DAM.read_text() + "\n[[damping_zones]]\nmin = [0.0, 0.0]\nmax = [1.0, 0.5]\nrate = 5.0\n")
    with pytest.raises(SceneError, match=r"damping_zones\[0\]: no direction given"):
        load_scene(path)


@pytest.mark.fast
def test_damping_zones_cannot_change_during_a_run(tmp_path):
    sim = Simulation(load_scene(with_zone(tmp_path)), "f64")
    with pytest.raises(ValueError, match=r"damping_zones.*cannot change during a run: it changes the walls"):
        sim.set_parameter("damping_zones[0].rate", 10.0)


# -- k(x) ------------------------------------------------------------------------------------------
@pytest.mark.fast
@pytest.mark.parametrize("precision", [np.float64, np.float32])
def test_k_rises_as_the_square_of_the_depth_into_the_zone(tmp_path, precision):
    """A zone over x in [1, 2] growing along -x (the waves come from x = 2): k = rate s^2 with
    s = (2 - x); a second zone over the same box growing along +y adds its own; outside, a is kept."""
    sc = load_scene(with_zone(tmp_path, lo="1.0, 0.0", hi="1.5, 0.4", e="-1.0, 0.0", rate=40.0,
                              extra=ZONE.format(lo="1.0, 0.0", hi="1.5, 0.4", e="0.0, 1.0", rate=10.0)))
    table = damping_rows(sc, precision)
    xs = np.array([[1.25, 0.0, 0.0], [1.0, 0.2, 0.0], [0.99, 0.2, 0.0], [1.2, 0.4, 0.0], [1.4999, 0.3999, 0.0],
                   [1.5, 0.1, 0.0]], dtype=precision)
    v = np.array([[2.0, -1.0, 0.0]] * len(xs), dtype=precision)
    a = np.full_like(v, 0.5)
    for i in range(len(xs)):
        damping_row(i, xs, v, table, a)
    assert a.dtype == precision
    # half way along x on the y zone's near face: 40 / 4; on the x zone's far face, half way up: 40 + 10 / 4
    assert a[0, 0] == precision(0.5 - 10.0 * 2.0) and a[1, 0] == precision(0.5 - 42.5 * 2.0)
    assert np.all(a[[2, 3, 5]] == precision(0.5))  # outside (the boxes are half-open: x < 1.5, y < 0.4)
    s_x = (1.5 - xs[:, 0].astype(float)) / 0.5
    s_y = xs[:, 1].astype(float) / 0.4
    inside = (xs[:, 0] >= 1.0) & (xs[:, 0] < 1.5) & (xs[:, 1] >= 0.0) & (xs[:, 1] < 0.4)
    k = np.where(inside, 40.0 * s_x ** 2 + 10.0 * s_y ** 2, 0.0)
    assert np.allclose(a, 0.5 - k[:, None] * v.astype(float), rtol=1e-5 if precision == np.float32 else 1e-14, atol=0.0)


# -- what it does to a flow ------------------------------------------------------------------------
def kinetic_energy(sim):
    s = sim.state
    n = s.n_owned
    return float(0.5 * np.sum(s.m[:n] * np.sum(s.v[:n].astype(float) ** 2, axis=1)))


@pytest.mark.fast
def test_a_zone_over_the_tank_takes_the_collapsing_column_s_energy(tmp_path):
    """The coarse dam break, 0.3 s: with a zone over the whole tank (k up to 50 / s) the fluid has a
    small part of the kinetic energy it has without; the same step count either way."""
    common = ["particles.spacing=0.03"]
    free = Simulation(load_scene(DAM, common), "f64")
    damped = Simulation(load_scene(with_zone(tmp_path, lo="0.0, 0.0", hi="1.6, 0.6", e="0.0, -1.0"), common), "f64")
    for sim in (free, damped):
        while sim.t < 0.3:
            sim.step(dt_cap=0.3 - sim.t)
    assert kinetic_energy(free) > 0.5  # J/m: the column is falling
    assert kinetic_energy(damped) < 0.2 * kinetic_energy(free), (kinetic_energy(damped), kinetic_energy(free))


@pytest.mark.fast
def test_two_and_three_peers_run_a_damped_wave_tank_as_one_process_bit_for_bit(tmp_path):
    sc = load_scene(WAVES, ["particles.spacing=0.02"])
    assert sc.damping_zones
    final = {}
    for peers in (1, 2, 3):
        dims = {"dims": (peers, 1, 1)} if peers > 1 else {}
        InProcessCluster(sc, peers, "f64", **dims).run(RunPlan(300, out=tmp_path / str(peers), progress=False))
        final[peers] = dict(np.load(tmp_path / str(peers) / "final.npz"))
    for peers in (2, 3):
        for k in ("id", "x", "v", "rho"):
            assert np.array_equal(final[1][k], final[peers][k]), (peers, k)
    zone = sc.damping_zones[0]
    inside = final[1]["x"][:, 0] >= zone.min[0]
    assert np.any(final[1]["v"][inside] != 0.0)  # the zone held moving particles


def test_the_recording_draws_the_damping_zone(tmp_path):
    from launch.cli import main
    from nodes.recording import blueprint, entity_steps
    assert main(["run", str(WAVES), "--steps", "20", "--set", "particles.spacing=0.02", "--set", "render.every=10",
                 "--quiet", "--out", str(tmp_path)]) == 0
    rrd = tmp_path / "run.rrd"
    assert "/damping_zones/0" in entity_steps(rrd)
    view = next(v for v in blueprint(rrd)["views"] if v["kind"] == "3D")
    assert "/damping_zones/**" in view["contents"]
