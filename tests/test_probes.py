"""Probes ([[probes]], sphcore/probes.py): the scene's checks, the interpolation on synthetic states,
N peers == one process bit for bit in probes.csv, a resumed run without doubled or lost rows, and
the hydrostatic tank measured by its probes."""
import math
from pathlib import Path

import numpy as np
import pytest

from launch.cli import main
from nodes.cluster import InProcessCluster
from nodes.driver import RunPlan
from sphcore import checkpoint
from sphcore.choices import Kernel
from sphcore.physics.kernels import kernel_constants, w
from sphcore.probes import Probes, kernel_values, wetted_length
from sphcore.scene import SceneError, load_scene
from sphcore.solver import Simulation

from test_steering import run_one

ROOT = Path(__file__).resolve().parent.parent
DAM2D = (ROOT / "configs" / "dam_break_2d.toml").read_text().split("\n[[probes]]", 1)[0]  # the scene, no probes
# wet from the start: in the column, on its left wall, on the floor; and the column's height
PROBES = """
[[probes]]
name = "p_column"
kind = "pressure"
at = [0.1, 0.1]

[[probes]]
name = "p_left_wall"
at = [0.0, 0.05]

[[probes]]
name = "p_right_wall"
at = [1.6, 0.02]

[[probes]]
name = "h_column"
kind = "height"
at = [0.1, 0.0]
"""
SMALL = ("particles.spacing=0.02", "output.probes_every=3")


def probe_scene(tmp_path, probes: str = PROBES, *overrides, base: str = DAM2D):
    path = tmp_path / "scene.toml"
    path.write_text(base + "\n" + probes)
    return load_scene(path, list(overrides))


# -- the scene's checks ----------------------------------------------------------------------------
BAD = [
    ('name = "p"\nkind = "velocity"\nat = [0.1, 0.1]', ["probes[0].kind = 'velocity'", "'pressure', 'height'"]),
    ('name = "p"\nat = [0.1]', ["probes[0].at = [0.1]", "2 or 3 components"]),
    ('name = "p"\nat = [0.1, 0.1, 0.5]', ["z must be 0", "probes[0].at"]),
    ('name = "p"\nat = "middle"', ["probes[0].at = 'middle'", "expected an array"]),
    ('name = "a,b"\nat = [0.1, 0.1]', ["probes[0].name = 'a,b'", "letters, digits"]),
    ('name = "1st"\nat = [0.1, 0.1]', ["probes[0].name = '1st'", "a letter"]),
    ('name = "t"\nat = [0.1, 0.1]', ["probes[0].name = 't'", "first columns"]),
    ('at = [0.1, 0.1]', ["probes[0]: no name given"]),
    ('name = "p"', ["probes[0]: no at given"]),
    ('name = "p"\nat = [0.1, 0.1]\nevery = 5', ["unknown key 'probes[0].every'", "allowed in [probes[0]]: name, kind, at, threshold"]),
    ('name = "p"\nat = [0.1, 0.1]\nthreshold = 2.0', ["probes[0].threshold = 2.0", "[0, 1]"]),
    ('name = "p"\nat = [0.1, 0.1]\n\n[[probes]]\nname = "p"\nat = [0.2, 0.1]',
     ["probes[1].name = 'p'", "already the name of probes[0]"]),
    ('name = "h"\nkind = "height"\nat = [0.1, 0.0]\ngauge = "float"', ["probes[0].gauge = 'float'", "'highest', 'wire'"]),
    ('name = "p"\nat = [0.1, 0.1]\ngauge = "wire"', ["probes[0].gauge = 'wire': a pressure probe has no gauge"]),
]


@pytest.mark.fast
@pytest.mark.parametrize("body, wanted", BAD, ids=[w[0].split()[0] for _, w in BAD])
def test_a_bad_probe_is_refused_naming_the_key_the_value_and_what_is_allowed(tmp_path, body, wanted):
    with pytest.raises(SceneError) as e:
        probe_scene(tmp_path, "[[probes]]\n" + body)
    for text in wanted:
        assert text in str(e.value), str(e.value)


@pytest.mark.fast
def test_the_output_key_and_a_height_probe_without_gravity_are_checked(tmp_path):
    with pytest.raises(SceneError, match=r"output.probes_every = -1: allowed range is \[0, 1e\+09\]"):
        probe_scene(tmp_path, PROBES, "output.probes_every=-1")
    with pytest.raises(SceneError, match=r"probes\[3\].kind = 'height': needs forces.gravity.*\[0.0, 0.0\]"):
        probe_scene(tmp_path, PROBES, "forces.gravity=[0.0, 0.0]")
    with pytest.raises(SceneError, match="a 3D scene needs 3 components"):
        probe_scene(tmp_path, PROBES, "scene.dim=3", "fluid.blocks[0].min=[0,0,0]", "fluid.blocks[0].max=[0.2,0.4,0.1]",
                    "domain.center=[0.8,0.3,0.05]", "domain.size=[1.6,0.6,0.1]", "forces.gravity=[0,-9.81,0]",
                    "forces.external=[0,0,0]")


@pytest.mark.fast
def test_a_probe_outside_the_domain_is_refused_before_the_first_step_and_sph_run_says_so(tmp_path, capsys):
    sc = probe_scene(tmp_path, PROBES + '\n[[probes]]\nname = "outside"\nat = [1.7, 0.1]\n', *SMALL)
    with pytest.raises(SceneError, match=r"probes\[4\].at = \[1.7, 0.1\]: outside the domain \(probe 'outside'\)"):
        Simulation(sc, "f64")
    rc = main(["run", str(tmp_path / "scene.toml"), "--set", SMALL[0], "--steps", "1", "--no-viewer", "--quiet",
               "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2 and "probes[4].at = [1.7, 0.1]: outside the domain" in err and "Traceback" not in err, err


@pytest.mark.fast
def test_the_resolved_scene_toml_holds_the_probes_and_reads_back_the_same(tmp_path):
    import dataclasses

    from sphcore.scene import scene_toml
    sc = probe_scene(tmp_path, PROBES, *SMALL)
    (tmp_path / "resolved.toml").write_text(scene_toml(sc.to_dict()))
    again = load_scene(tmp_path / "resolved.toml")
    assert dataclasses.replace(again, source="") == dataclasses.replace(sc, source="")
    assert [p.name for p in again.probes] == ["p_column", "p_left_wall", "p_right_wall", "h_column"]


@pytest.mark.fast
def test_probes_cannot_change_during_a_run_but_their_period_can(tmp_path):
    from sphcore.scene import key_control, live_change, LIVE
    sc = probe_scene(tmp_path)
    assert key_control("output.probes_every") is LIVE
    assert live_change(sc, "output.probes_every=1")[1].output.probes_every == 1
    for key in ("probes[0].at=[0.2, 0.1]", "probes[1].kind=height"):
        with pytest.raises(SceneError, match="cannot change during a run: it fixes the columns of probes.csv"):
            live_change(sc, key)


# -- the interpolation on synthetic states ---------------------------------------------------------
@pytest.mark.fast
@pytest.mark.parametrize("kernel", list(Kernel), ids=[k.name for k in Kernel])
def test_the_numpy_kernel_is_the_kernel_of_the_passes(kernel):
    H = 0.046
    s_w = kernel_constants(kernel, 2, H)[0]
    r = np.linspace(0.0, 1.2 * H, 97)
    assert np.allclose(kernel_values(kernel, r, H, s_w), [w(int(kernel), float(v), H, s_w) for v in r],
                       rtol=1e-13, atol=0.0)


def lattice(lo, hi, dx, rho0=1000.0):
    """A 2D lattice at rest density: x (n, 3), m, rho."""
    xs = np.arange(lo[0] + 0.5 * dx, hi[0], dx)
    ys = np.arange(lo[1] + 0.5 * dx, hi[1], dx)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    x = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    return x, np.full(len(x), rho0 * dx * dx), np.full(len(x), rho0)


@pytest.fixture(scope="module")
def tank_probes(tmp_path_factory):
    """The Probes of the 2D dam break's tank (dx = 0.02) with pressure probes in the bulk, off the
    lattice's symmetry points, and on the floor."""
    tmp = tmp_path_factory.mktemp("probes")
    body = "".join(f'\n[[probes]]\nname = "{n}"\nat = [{x}, {y}]\n'
                   for n, x, y in (("bulk", 0.8, 0.3), ("offset", 0.8137, 0.2891), ("floor", 0.8, 0.0),
                                   ("wall", 0.0, 0.3)))
    return Probes(Simulation(probe_scene(tmp, body, "particles.spacing=0.02"), "f64"))


@pytest.mark.fast
def test_a_constant_pressure_is_read_exactly_in_the_bulk_and_at_a_wall(tank_probes):
    x, m, rho = lattice((0.0, 0.0), (1.6, 0.6), 0.02)
    values = tank_probes.values(tank_probes.partial_sums(x, m, rho, np.full(len(x), 1234.5)))
    assert np.allclose(values, 1234.5, rtol=1e-9, atol=0.0), values


@pytest.mark.fast
def test_a_linear_pressure_is_reproduced_in_the_bulk_and_biased_by_its_gradient_at_a_wall(tank_probes):
    # Given a lattice with p = 9810 (0.6 - y) + 500 x (Pa)
    x, m, rho = lattice((0.0, 0.0), (1.6, 0.6), 0.02)
    p = 9810.0 * (0.6 - x[:, 1]) + 500.0 * x[:, 0]
    exact = [9810.0 * (0.6 - pt[1]) + 500.0 * pt[0] for pt in tank_probes.points]
    values = tank_probes.values(tank_probes.partial_sums(x, m, rho, p))
    err = np.abs(values - exact) / (9810.0 * 0.6)
    # Then in the bulk it is exact to round-off at a lattice point and within 1e-4 of rho0 g H off it
    # (the lattice's first kernel moment about the point)
    assert err[0] < 1e-10 and err[1] < 1e-4, err
    # and on a wall it is the pressure at the centroid of the fluid in the support, a distance c inside
    # (0.24 H here): the floor reads the vertical gradient times c, the side wall the horizontal one
    H, scale = tank_probes.H, 9810.0 * 0.6
    c_floor, c_wall = err[2] * scale / 9810.0, err[3] * scale / 500.0
    assert 0.2 * H < c_floor < 0.3 * H and abs(c_wall - c_floor) < 1e-3 * c_floor, (c_floor, c_wall, H)
    assert values[2] < exact[2] and values[3] > exact[3]  # the pressure inside: lower above the floor


@pytest.mark.fast
def test_a_dry_point_reads_zero_and_a_dry_line_nan(tmp_path):
    probes = Probes(Simulation(probe_scene(tmp_path, PROBES, "particles.spacing=0.02"), "f64"))
    x, m, rho = lattice((1.0, 0.0), (1.2, 0.1), 0.02)  # a puddle far from every probe
    values = probes.values(probes.partial_sums(x, m, rho, np.full(len(x), 100.0)))
    assert list(values[:3]) == [0.0, 0.0, 0.0] and math.isnan(values[3]), values


@pytest.mark.fast
def test_a_height_probe_finds_a_flat_surface_within_a_tenth_of_a_spacing(tmp_path):
    probes = Probes(Simulation(probe_scene(tmp_path, PROBES, "particles.spacing=0.02"), "f64"))
    for rows, lift in ((10, 0.0), (15, 0.0037), (22, 0.011)):  # the surface between the line's samples too
        x, m, rho = lattice((0.0, 0.0), (0.4, rows * 0.02), 0.02)
        x[:, 1] += lift
        fill = rows * 0.02 + lift  # half a spacing above the top row
        h = probes.values(probes.partial_sums(x, m, rho, np.zeros(len(x))))[3]
        assert abs(h - fill) < 0.1 * 0.02, (fill, h)


WIRE = PROBES + """
[[probes]]
name = "h_wire"
kind = "height"
at = [0.1, 0.0]
gauge = "wire"
"""


@pytest.mark.fast
def test_the_wetted_length_of_a_line_counts_the_wet_stretches_and_skips_its_gaps():
    s = np.round(np.arange(11) * 0.1, 12)  # 0, 0.1, ..., 1.0
    phi = np.array([0.5, 1.0, 1.0, 0.75, 0.25, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
    # wet from 0 to the crossing at 0.35, and around the sample at 0.7 (0.65 to 0.75)
    assert wetted_length(s, phi, 0.5) == pytest.approx(0.35 + 0.1)
    # a line with its samples inside an obstacle left out: the gap between 0.3 and 0.7 adds nothing
    keep = np.array([0, 1, 2, 3, 7, 8, 9, 10])
    assert wetted_length(s[keep], np.array([1, 1, 1, 1, 1, 1, 0, 0.0]), 0.5) == pytest.approx(0.3 + 0.15)
    assert wetted_length(s, np.zeros(11), 0.5) == 0.0 and wetted_length(s[:1], np.ones(1), 0.5) == 0.0


@pytest.mark.fast
def test_a_wire_gauge_reads_the_column_and_adds_only_the_thickness_of_spray_above_it(tmp_path):
    probes = Probes(Simulation(probe_scene(tmp_path, WIRE, "particles.spacing=0.02"), "f64"))
    dx, fill = 0.02, 15 * 0.02
    column = lattice((0.0, 0.0), (0.4, fill), dx)
    blob = lattice((0.06, 0.48), (0.14, 0.56), dx)  # 4 x 4 particles of spray over the probes' line x = 0.1
    highest, wire = 3, 4

    def read(*parts):
        x, m, rho = (np.concatenate(a) for a in zip(*parts))
        return probes.values(probes.partial_sums(x, m, rho, np.zeros(len(x))))

    # the column alone: both gauges read its surface
    alone = read(column)
    assert abs(alone[highest] - fill) < 0.1 * dx and abs(alone[wire] - fill) < 0.1 * dx, alone
    # the spray alone: the wire reads the line's lowest point (the floor, y = 0) plus the blob's thickness
    thickness = read(blob)[wire]
    assert 0.5 * 0.08 < thickness < 0.08 + dx, thickness
    # both: the highest wet point jumps to the spray's top, the wire adds the spray's thickness only
    both = read(column, blob)
    assert abs(both[highest] - 0.56) < 0.5 * dx, both
    assert abs(both[wire] - (fill + thickness)) < 0.1 * dx, (both, fill, thickness)


# -- a run: N peers == one process, a resume ---------------------------------------------------------
@pytest.mark.fast
def test_two_peers_write_the_same_probes_csv_as_one_process_bit_for_bit(tmp_path):
    # Given the small 2D dam break with wet probes, sampled every 3 steps
    sc = probe_scene(tmp_path, PROBES, *SMALL)
    # When it runs 60 steps in one process and on two in-process peers split across the column
    summary, _, _ = run_one(sc, tmp_path / "one", steps=60)
    two = InProcessCluster(sc, 2, "f64", dims=(2, 1, 1)).run(RunPlan(60, out=tmp_path / "two", progress=False))
    # Then probes.csv is the same text (every float written by repr: its exact bits), 20 rows
    one_csv, two_csv = ((tmp_path / d / "probes.csv").read_text() for d in ("one", "two"))
    assert one_csv == two_csv
    lines = one_csv.splitlines()
    assert lines[0] == "step,t,p_column,p_left_wall,p_right_wall,h_column"
    assert [int(r.split(",")[0]) for r in lines[1:]] == list(range(3, 61, 3))
    # And the values are the column's: wet pressure probes, a dry one, a height near 0.4 m
    last = [float(v) for v in lines[-1].split(",")]
    assert last[2] > 0.0 and last[3] > 0.0 and last[4] == 0.0 and abs(last[5] - 0.4) < 0.02, last
    for s in (summary, two):
        assert s["probes"]["units"] == {"p_column": "Pa", "p_left_wall": "Pa", "p_right_wall": "Pa", "h_column": "m"}
        assert s["probes"]["last"]["step"] == 60 and s["probes"]["last"]["p_column"] == last[2]


@pytest.mark.fast
def test_a_resumed_run_neither_doubles_nor_loses_rows(tmp_path):
    # Given an uninterrupted run to step 40, and a run into another folder checkpointed at step 20
    # that went on to step 31 (its rows after step 20 are what a crash would leave behind)
    sc = probe_scene(tmp_path, PROBES, *SMALL)
    run_one(sc, tmp_path / "whole", steps=40)
    out = tmp_path / "resumed"
    run_one(sc, out, steps=31, checkpoint_every=20)
    assert (out / "probes.csv").read_text().splitlines()[-1].startswith("30,")
    # When it is resumed from the checkpoint at step 20 into the same folder, to step 40
    ckpt = checkpoint.load(out / "checkpoints")
    assert ckpt.manifest["step"] == 20
    run_one(sc, out, steps=40, resume=ckpt)
    # Then probes.csv is the uninterrupted run's, row for row
    whole, resumed = ((d / "probes.csv").read_text() for d in (tmp_path / "whole", out))
    steps = [int(r.split(",")[0]) for r in resumed.splitlines()[1:]]
    assert steps == list(range(3, 40, 3)), steps
    assert resumed == whole


@pytest.mark.fast
def test_a_resumed_run_refuses_a_probes_csv_that_is_not_text_with_one_line_and_keeps_it(tmp_path, capsys):
    # Given a run checkpointed at step 2 whose probes.csv was replaced by binary bytes
    out = tmp_path / "run"
    assert main(["run", str(ROOT / "configs" / "dam_break_2d.toml"), "--steps", "2", "--checkpoint-every", "2",
                 "--set", "output.probes_every=1", "--out", str(out), "--quiet", "--no-viewer"]) == 0
    garbage = bytes([0xBB, 0xCF, 0xA1, 0x1B]) * 64
    (out / "probes.csv").write_bytes(garbage)
    capsys.readouterr()
    # When it is resumed into the same folder (which keeps the probes.csv rows up to step 2)
    rc = main(["run", "--resume", str(out), "--steps", "4", "--out", str(out), "--quiet", "--no-viewer"])
    # Then exit 2, one line naming the file and why, and the file is left as it was
    err = capsys.readouterr().err
    assert rc == 2, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert "Traceback" not in err and len(lines) == 1 and lines[0].startswith("sph run: error: "), err
    line = lines[0]
    assert f"{out / 'probes.csv'}: not a probes.csv (byte 0xbb at offset 0 is not UTF-8 text)" in line, line
    assert (out / "probes.csv").read_bytes() == garbage


# -- validation: the hydrostatic tank --------------------------------------------------------------
@pytest.mark.slow  # a validation case (minutes): the slow tier; the probes' sampling is tested above
def test_the_hydrostatic_tank_measured_by_its_probes_passes(tmp_path, capsys):
    assert main(["validate", "hydrostatic_probes", "--quick", "--out", str(tmp_path)]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("hydrostatic_probes.")]
    assert len(lines) == 3 and all(line.split()[3] == "PASS" for line in lines), lines
    assert (tmp_path / "hydrostatic_probes.png").stat().st_size > 0


# -- the viewer ------------------------------------------------------------------------------------
def test_the_recording_plots_every_probe_sample_at_its_step(tmp_path):
    # Given a recorded run with frames every 20 steps and probes every 3
    from nodes.recording import blueprint, entity_steps
    probe_scene(tmp_path)
    out = tmp_path / "out"
    assert main(["run", str(tmp_path / "scene.toml"), "--set", SMALL[0], "--set", SMALL[1], "--set", "render.every=20",
                 "--precision", "f64", "--steps", "60", "--out", str(out), "--quiet"]) == 0
    # Then every sample is in the recording at its own step, under probes/<name>, and the blueprint
    # plots them (pressure and height apart)
    steps = entity_steps(out / "run.rrd")
    for name in ("p_column", "p_left_wall", "p_right_wall", "h_column"):
        assert steps.get(f"/probes/{name}") == list(range(3, 61, 3)), (name, steps.get(f"/probes/{name}"))
    views = {v["name"]: v for v in blueprint(out / "run.rrd")["views"]}
    assert views["Probes: pressure (Pa)"]["origin"] == "/probes"
    assert "Probes: surface height (m)" in views


@pytest.mark.fast
def test_malformed_probe_statistics_from_the_wire_are_skipped(tmp_path):
    import time

    from nodes.recording import entity_steps
    from nodes.viewer import Viewer, open_recording
    from sphcore.render import Framelet
    sc = probe_scene(tmp_path, PROBES, "particles.spacing=0.05")
    rec = open_recording("test", tmp_path / "r.rrd")
    v = Viewer(sc, ((0.0, 0.0, 0.0), (1.6, 0.6, 0.0)), rec, world=1, particles=12)
    empty = Framelet(0, 0, 0, np.zeros((0, 0, 3), np.uint8), np.zeros((0, 0), np.float32), np.zeros((0, 0), np.int64))
    stats = {"sim_time": 0.1, "particles": 12, "bytes_sent": 0, "stage_ms": {}, "kinetic_energy": 0.0,
             "max_density_deviation": 0.0, "wall_time": time.time()}
    v.add(4, 0, empty, dict(stats, probes={"names": ["a", "b"], "samples": [
        [1, 0.01, [1.0, None]], [2, "x", [1.0, 2.0]], [3, 0.03, [1.0]], "bad", [4, 0.04, [float("inf"), 1.0]]]}))
    v.add(8, 0, empty, dict(stats, probes={"names": ["../../x"], "samples": [[5, 0.05, [1.0]]]}))
    v.close()
    del rec
    steps = entity_steps(tmp_path / "r.rrd")
    assert steps.get("/probes/a") == [1] and "/probes/b" not in steps, steps
    assert not [e for e in steps if e.startswith("/probes/") and e not in ("/probes/a",)]


def test_two_peer_processes_over_zenoh_write_the_same_probes_csv_as_one_process(tmp_path):
    # Given the small dam break with probes sampled every step, as `sph run` and `sph run --peers 2`
    import subprocess
    import sys
    probe_scene(tmp_path)
    base = [sys.executable, "-m", "launch.cli", "run", str(tmp_path / "scene.toml"), "--set", SMALL[0], "--set",
            "output.probes_every=1", "--precision", "f64", "--steps", "150", "--no-viewer", "--quiet"]
    for out, extra in (("one", []), ("two", ["--peers", "2", "--insecure"])):
        proc = subprocess.run(base + ["--out", str(tmp_path / out)] + extra, cwd=ROOT, capture_output=True, text=True,
                              timeout=300)
        assert proc.returncode == 0, proc.stderr
    # Then both files hold the same 150 rows, to the last bit
    one, two = ((tmp_path / d / "probes.csv").read_text() for d in ("one", "two"))
    assert len(one.splitlines()) == 151 and one == two
