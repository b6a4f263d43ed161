"""A scene far from the world's origin runs relative to its own (sphcore.scene.scene_origin):
float32 a million metres away computes what the same scene computes at the origin, bit for bit, on
one process and on two peers; what a user reads (scene.toml, final.npz's origin, summary.json, the
VTK series, final.npz, probes.csv's heights) is in world coordinates. Before, the 2D hydrostatic tank moved
1e6 m collapsed its 2500 particles onto 450 positions within 200 steps, with exit 0."""
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from launch.cli import main
from nodes.cluster import InProcessCluster
from nodes.driver import RunPlan
from sphcore import checkpoint
from sphcore.checkpoint import CheckpointError
from sphcore.scene import live_change, load_scene, scene_toml, shifted
from sphcore.solver import Simulation

from conftest import CONFIGS
from test_probes import DAM2D
from test_steering import run_one

# test_probes' probes, off the walls: at 1e6 m the walls' float64 coordinates carry 1e-10 m of
# rounding, enough to put a probe written exactly on a wall outside it (and the run refuses that)
PROBES = """
[[probes]]
name = "p_column"
at = [0.1, 0.1]

[[probes]]
name = "p_left_wall"
at = [0.005, 0.05]

[[probes]]
name = "p_right_wall"
at = [1.595, 0.02]

[[probes]]
name = "h_column"
kind = "height"
at = [0.1, 0.0001]
"""

FAR = (1.0e6, 1.0e5, 0.0)  # multiples of every small domain's power-of-two size: the origin is exactly this


def moved(scene, offset, path: Path) -> Path:
    """``scene`` moved by ``offset`` (m) in the world, written as a scene file at ``path``."""
    world = dataclasses.replace(shifted(scene, offset), origin=(0.0, 0.0, 0.0))
    path.write_text(scene_toml(world.to_dict()))
    return path


def dam(tmp_path, *overrides):
    path = tmp_path / "dam.toml"
    path.write_text(DAM2D + "\n" + PROBES)
    return load_scene(path, ["particles.spacing=0.02", "output.probes_every=3", *overrides])


@pytest.mark.fast
@pytest.mark.parametrize("config", sorted(p.name for p in CONFIGS.glob("*.toml")))
def test_every_shipped_scene_runs_where_it_is(config):
    """Scenes within twice their size of the world's origin keep it, so their results are unchanged."""
    assert load_scene(CONFIGS / config).origin == (0.0, 0.0, 0.0)


@pytest.mark.fast
def test_a_far_scene_is_held_relative_to_its_origin_and_written_back_in_world_coordinates(tmp_path):
    base = dam(tmp_path)
    far = load_scene(moved(base, FAR, tmp_path / "far.toml"))
    assert far.origin == FAR
    # held: every position as the scene at the origin has it (the container, blocks, probes), up to
    # the rounding of the world's float64 (1000000.8 is 1e6 + 0.8000000000465661): 1e-10 m
    close = lambda a, b: np.allclose(a, b, rtol=0.0, atol=2e-10)  # noqa: E731
    assert close(far.domain.center, base.domain.center) and close(far.probes[0].at, base.probes[0].at)
    assert all(close(f.min, b.min) and close(f.max, b.max) for f, b in zip(far.fluid.blocks, base.fluid.blocks))
    # written: world coordinates, which read back to the same scene
    d = far.to_dict()
    assert d["domain"]["center"] == [c + o for c, o in zip(base.domain.center, FAR)]  # as the file says
    assert d["probes"][0]["at"] == [c + o for c, o in zip(base.probes[0].at, FAR)]
    (tmp_path / "again.toml").write_text(scene_toml(d))
    assert dataclasses.replace(load_scene(tmp_path / "again.toml"), source=far.source) == far
    # a live change is given in world coordinates too
    key, changed = live_change(far, "forces.central_center=[1000000.5, 100000.25]")
    assert key == "forces.central_center" and changed.forces.central_center == (0.5, 0.25, 0.0)  # dyadic: exact


@pytest.mark.fast
def test_float32_a_million_metres_away_computes_what_it_computes_at_the_origin(tmp_path):
    # Given the small 2D dam break with probes, and the same scene moved 1e6 m along x and 1e5 m up
    base = dam(tmp_path)
    far = load_scene(moved(base, FAR, tmp_path / "far.toml"))
    # When both run 60 steps in float32, the far one also on two peers split across the column
    runs = {"origin": (base, 1), "far": (far, 1), "far, 2 peers": (far, 2)}
    out = {}
    for name, (sc, peers) in runs.items():
        cluster = InProcessCluster(sc, peers, "f32", **({"dims": (2, 1, 1)} if peers > 1 else {}))
        summary = cluster.run(RunPlan(60, out=tmp_path / name, progress=False))
        out[name] = summary, dict(np.load(tmp_path / name / "final.npz")), (tmp_path / name / "probes.csv")
    # Then every particle is where it is at the origin, to the last bit, relative to the far origin
    (s0, a0, p0), (s1, a1, p1), (s2, a2, p2) = out.values()
    # (final.npz holds world coordinates, in float64 for the far runs: exact, so the origin comes off exactly)
    assert a0["x"].dtype == np.float32 and a1["x"].dtype == np.float64
    assert np.array_equal(a1["x"] - FAR, a0["x"].astype(np.float64)) and np.array_equal(a1["x"], a2["x"])
    for k in ("id", "v", "rho"):
        assert np.array_equal(a0[k], a1[k]) and np.array_equal(a1[k], a2[k]), k
    assert len(np.unique(a1["x"], axis=0)) == len(a1["x"])
    assert s0["origin"] == [0.0, 0.0, 0.0] and s1["origin"] == list(FAR) == s2["origin"]
    # And what the user reads is in world coordinates: scene.toml, the heights of probes.csv
    assert load_scene(tmp_path / "far" / "scene.toml").origin == FAR
    rows0, rows1 = ([r.split(",") for r in p.read_text().splitlines()[1:]] for p in (p0, p1))
    assert p1.read_text() == p2.read_text() and len(rows0) == 20
    for r0, r1 in zip(rows0, rows1):
        assert r0[:2] == r1[:2]  # step and t: the same text
        # the pressures: at points 1e-11 m apart (the world file's rounding at 1e6 m), summed in the
        # probes' integer units (one unit is ~1e-8 of these values)
        assert [float(v) for v in r1[2:5]] == pytest.approx([float(v) for v in r0[2:5]], rel=1e-7, abs=1e-6)
        assert float(r1[5]) - FAR[1] == pytest.approx(float(r0[5]), abs=1e-9)  # the height, 1e5 m higher


def test_the_vtk_series_is_in_world_coordinates_in_float64(tmp_path):
    import pyvista as pv
    base = load_scene(CONFIGS / "tiny.toml")
    far = moved(base, (1.0e6, 0.0, -2.0e6), tmp_path / "far.toml")
    for name, path in (("origin", CONFIGS / "tiny.toml"), ("far", far)):
        assert main(["run", str(path), "--precision", "f32", "--steps", "10", "--vtk", "10", "--set",
                     "output.surface=true", "--no-viewer", "--quiet", "--out", str(tmp_path / name)]) == 0
    clouds = {}
    for name in ("origin", "far"):
        reader = pv.PVDReader(str(tmp_path / name / "particles.pvd"))
        reader.set_active_time_value(reader.time_values[-1])
        clouds[name] = reader.read()[0]
        surface = pv.PVDReader(str(tmp_path / name / "surface.pvd"))
        surface.set_active_time_value(surface.time_values[-1])
        clouds[name + " surface"] = surface.read()[0]
    order = [np.argsort(clouds[n].point_data["id"]) for n in ("origin", "far")]
    x0, x1 = (clouds[n].points[o] for n, o in zip(("origin", "far"), order))
    assert x1.dtype == np.float64
    assert np.array_equal(x1 - (1.0e6, 0.0, -2.0e6), x0)  # exact: the far origin is a power of two's multiple
    s0, s1 = clouds["origin surface"].points, clouds["far surface"].points
    assert len(s0) > 100 and np.allclose(s1 - (1.0e6, 0.0, -2.0e6), s0, rtol=0, atol=1e-6)


@pytest.mark.fast
def test_a_far_run_resumes_to_the_continuous_run_and_a_checkpoint_of_another_origin_is_refused(tmp_path):
    far = load_scene(moved(dam(tmp_path), FAR, tmp_path / "far.toml"))
    whole, _, _ = run_one(far, tmp_path / "whole", 40, precision="f32")
    run_one(far, tmp_path / "part", 20, checkpoint_every=20, precision="f32")
    ckpt = checkpoint.load(tmp_path / "part" / "checkpoints")
    assert ckpt.manifest["origin"] == list(FAR)
    resumed, _, _ = run_one(far, tmp_path / "part", 40, resume=ckpt, precision="f32")
    assert resumed["steps"] == whole["steps"] == 40
    a, b = (np.load(tmp_path / d / "final.npz") for d in ("whole", "part"))
    assert np.array_equal(a["x"], b["x"]) and np.array_equal(a["v"], b["v"])
    ckpt = checkpoint.load(tmp_path / "part" / "checkpoints")
    ckpt.manifest["origin"] = [0.0, 0.0, 0.0]  # positions relative to another point: refused, not misplaced
    with pytest.raises(CheckpointError, match=r"origin = \[0.0, 0.0, 0.0\]"):
        checkpoint.restore(Simulation(far, "f32"), ckpt)
