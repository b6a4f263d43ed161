"""The viewer: recorded runs hold every entity for every rendered step and a blueprint that shows the
composite's RGB; N peers' composite equals one peer's image; incomplete frames are composited and
marked; a viewer behind Rerun drops frames instead of holding the run; the viewer follows camera
switches and settings changed during the run."""
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from launch.cli import main
from nodes.recording import blueprint, depth_images, entity_steps, images, text_logs
from nodes.viewer import Viewer, frame_arrays, frame_from_arrays, open_recording
from sphcore.render import Framelet

from conftest import scene

ROOT = Path(__file__).resolve().parent.parent
DAM = ["--set", "particles.spacing=0.05", "--set", "render.every=20", "--set", "render.points_every=7",
       "--set", "render.surface_every=1", "--precision", "f64", "--steps", "60"]
PER_STEP = ["/composite/rgb", "/composite/depth", "/composite/peers", "/peers/0/rgb", "/fluid/points", "/fluid/surface",
            "/stats/kinetic_energy", "/stats/max_density_deviation", "/stats/composite_latency_ms",
            "/stats/particles/peer0", "/stats/bytes_sent_mb/peer0", "/stats/stage_ms/forces/peer0",
            "/stats/stage_ms/render/peer0"]


@pytest.fixture(scope="module")
def one_peer(tmp_path_factory):
    out = tmp_path_factory.mktemp("one")
    assert main(["run", str(ROOT / "configs" / "dam_break.toml"), *DAM, "--out", str(out), "--quiet"]) == 0
    return out


def test_a_recorded_run_holds_every_entity_for_every_rendered_step(one_peer):
    steps = entity_steps(one_peer / "run.rrd")
    for entity in PER_STEP:
        assert steps.get(entity) == [20, 40, 60], entity
    assert steps["/domain"] == [] and steps["/info"] == []  # static
    assert "/composite/status" not in steps  # every frame was complete


def test_the_recording_carries_a_blueprint_that_shows_the_composite_rgb(one_peer):
    bp = blueprint(one_peer / "run.rrd")
    views = {v["name"]: v for v in bp["views"]}
    # the composite: RGB visible, depth hidden (but there), in the widest column
    comp = views["Composite"]
    assert (comp["kind"], comp["origin"]) == ("2D", "/composite")
    assert comp["hidden"] == ["/composite/depth"]
    assert [3.0, 2.0] in [c["shares"] for c in bp["containers"]]
    # a 3D view of the walls and the point cloud, an event log, the legend, a few plots
    assert "/fluid/**" in views["3D (drag to orbit)"]["contents"] and views["3D (drag to orbit)"]["kind"] == "3D"
    assert set(views["Events"]["contents"]) == {"/control", "/events", "/composite/status"}
    assert views["Legend"]["origin"] == "/legend"
    assert 4 <= sum(v["kind"] == "TimeSeries" for v in bp["views"]) <= 8
    # what the blueprint shows is there: a JPEG composite, its depth where the image shows fluid
    rgb, depth = images(one_peer / "run.rrd")[60], depth_images(one_peer / "run.rrd")[60]
    from sphcore.render import BACKGROUND
    fluid = depth > 0
    assert rgb.shape[:2] == depth.shape and fluid.mean() > 0.02
    assert (np.abs(rgb[fluid].astype(int) - BACKGROUND).max(axis=1) > 16).mean() > 0.95
    assert text_logs(one_peer / "run.rrd", "/legend")[0].startswith("# Colour: speed")


def test_two_peer_composite_equals_the_one_peer_image(one_peer, tmp_path):
    # Given the same run as 2 peer processes with a viewer process recording the composite
    done = subprocess.run([sys.executable, "-m", "launch.cli", "run", "configs/dam_break.toml", *DAM, "--peers", "2",
                           "--out", str(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    # Then every composited frame is pixel-identical to the single process's image of all particles
    one, two = images(one_peer / "run.rrd"), images(tmp_path / "run.rrd")
    assert sorted(two) == [20, 40, 60]
    for step in one:
        assert np.array_equal(one[step], two[step]), step
    assert (one[60] != one[60][0, 0]).any(axis=-1).mean() > 0.05  # the image shows something
    steps = entity_steps(tmp_path / "run.rrd")
    assert steps["/peers/1/rgb"] == [20, 40, 60] and steps["/stats/particles/peer1"] == [20, 40, 60]
    assert "/composite/status" not in steps
    import json
    shown = json.loads((tmp_path / "summary.json").read_text())["viewer"]  # from the viewer process
    assert shown["frames"] == 3 and shown["dropped_frames"] == 0 and shown["composite_latency_ms"]["max"] > 0
    assert shown["record_mb"] == pytest.approx((tmp_path / "run.rrd").stat().st_size / 1e6, rel=1e-3)
    # and the live surface, assembled from two peers' pieces, is the one process's surface: the same
    # closed volume, and every vertex of one near the other's (near the cut a peer's ghosts hold the
    # positions of the step's start, so the two are close, not equal)
    from nodes.recording import enclosed_volume, meshes
    whole, split = meshes(one_peer / "run.rrd"), meshes(tmp_path / "run.rrd")
    assert sorted(whole) == sorted(split) == [20, 40, 60]
    for step in whole:
        assert enclosed_volume(*split[step]) == pytest.approx(enclosed_volume(*whole[step]), rel=0.01), step
        a, b = whole[step][0].astype(np.float64), split[step][0].astype(np.float64)
        gap = np.sqrt(((b[:, None, :] - a[None, :, :]) ** 2).sum(axis=2)).min(axis=1)
        assert gap.max() < 0.25 * 0.05, (step, gap.max())  # a quarter of a spacing


def test_an_incomplete_frame_is_composited_from_what_arrived_and_marked(tmp_path):
    sc = scene("tiny")
    rec = open_recording("test", tmp_path / "r.rrd")
    v = Viewer(sc, ((0, 0, 0), (0.15, 0.2, 0.15)), rec, world=2, particles=10, frame_timeout=0.5)
    f = Framelet(0, 10, 20, np.full((3, 4, 3), 200, np.uint8), np.ones((3, 4), np.float32), np.arange(12).reshape(3, 4))
    stats = {"sim_time": 0.1, "particles": 12, "bytes_sent": 0, "stage_ms": {}, "kinetic_energy": 0.0,
             "max_density_deviation": 0.0, "wall_time": 0.0}
    v.add(5, 0, f, stats)          # peer 1's framelet of step 5 never comes
    assert v.frames == 0
    v.add(7, 0, f, stats)
    v.add(7, 1, f, stats)          # a later frame completes: step 5 goes out first, marked
    v.expire()
    v.close()
    assert v.frames == 2 and v.incomplete == 1 and v.dropped == 0
    del rec, v
    assert text_logs(tmp_path / "r.rrd", "/composite/status") == [
        "step 5: incomplete frame, no framelet from peer(s) [1]"]
    assert np.abs(images(tmp_path / "r.rrd")[7][21, 11].astype(int) - 200).max() <= 8  # JPEG


def test_framelet_messages_round_trip_and_reject_mismatched_planes():
    f = Framelet(3, 1, 2, np.zeros((2, 5, 3), np.uint8), np.zeros((2, 5), np.float32), np.zeros((2, 5), np.int64))
    arrays = frame_arrays(f, {"a": 1}, (np.zeros((4, 3)), np.full((4, 3), 9, np.uint8)))
    g, stats, (xyz, rgb), surface = frame_from_arrays(3, arrays)
    assert (g.x0, g.y0, g.w, g.h, stats, xyz.shape, rgb.tolist()[0]) == (1, 2, 5, 2, {"a": 1}, (4, 3), [9, 9, 9])
    assert surface is None
    with pytest.raises(ValueError, match="point_colours"):
        frame_from_arrays(3, dict(arrays, point_colours=np.zeros((3, 3), np.uint8)))
    arrays["rect"] = np.array([1, 2, 6, 2])
    with pytest.raises(ValueError, match="rectangle"):
        frame_from_arrays(3, arrays)


def test_a_viewer_joins_a_running_run_and_sees_the_same_frames(tmp_path):
    import re

    from test_control import send
    from test_peers import Lines, sph
    # Given a 2-peer run (with its own recording viewer), paused after step 100 so that the second
    # viewer surely joins while it runs (the run alone takes ~15 s: long enough for the pause to land
    # before the end on a loaded machine, where 900 steps were once over before it did)
    p = sph("run", "configs/dam_break.toml", "--peers", "2", "--steps", "2000", "--out", str(tmp_path / "run"),
            "--set", "particles.spacing=0.04", "--set", "run.log_every=50", "--set", "render.every=50")
    log = Lines(p.stderr)
    log.wait_for("peer 0 sph.run INFO step 100", timeout=120)
    launch = next(line for line in log.lines if "endpoints" in line)
    run_id = re.search(r"run (\w+):", launch).group(1)
    endpoints = re.findall(r"(tls/[\d.]+:\d+)", launch)
    send(run_id, endpoints[0], tmp_path / "run" / "tls", "pause")
    # When a second viewer joins by connecting to the peers' endpoints, and the run resumes
    joined = subprocess.Popen([sys.executable, "-m", "launch.cli", "viewer", "configs/dam_break.toml", "--run-id",
                               run_id, *sum((["--zenoh", e] for e in endpoints), []), "--world", "2",
                               "--tls", str(tmp_path / "run" / "tls"), "--record",
                               str(tmp_path / "joined.rrd"), "--set", "particles.spacing=0.04",
                               "--set", "render.every=50", "--idle-timeout", "60"],
                              cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert joined.stdout.readline().strip() == "viewer ready"
        time.sleep(1.0)  # its subscription reaches the peers
        send(run_id, endpoints[0], tmp_path / "run" / "tls", "resume")
        out, err = joined.communicate(timeout=300)
    finally:
        joined.kill()
    # Then the run is undisturbed, and the joined viewer recorded the later frames identically
    assert p.wait(timeout=300) == 0, log.text()
    assert joined.returncode == 0, err
    mine, theirs = images(tmp_path / "joined.rrd"), images(tmp_path / "run" / "run.rrd")
    assert len(mine) >= 3 and max(mine) == 2000 and min(mine) > 100
    # A frame whose second framelet came more than frame_timeout (2 s) after the first is composited
    # incomplete, and marked so; on a loaded machine that can happen in one viewer and not the other
    # (seen once in CI). Those frames differ by design; every complete frame must match bit for bit.
    marked = incomplete_steps(tmp_path / "joined.rrd") | incomplete_steps(tmp_path / "run" / "run.rrd")
    complete = [step for step in mine if step not in marked]
    assert len(complete) >= len(mine) - 2 and len(complete) >= 3, marked
    for step in complete:
        assert np.array_equal(mine[step], theirs[step]), step


def incomplete_steps(rrd: Path) -> set[int]:
    import re
    return {int(re.match(r"step (\d+):", t).group(1)) for t in text_logs(rrd, "/composite/status")}


class SlowRerun:
    """A recording stream whose channel blocks (a live viewer that cannot keep up): each composite
    takes ``delay`` s to log. Records the steps whose composite went out."""

    def __init__(self, delay: float):
        self.delay, self.logged, self.step = delay, [], None

    def set_time(self, timeline, sequence=None, duration=None):
        if timeline == "step":
            self.step = sequence

    def log(self, entity, *args, **kwargs):
        if entity == "composite/rgb":
            time.sleep(self.delay)
            self.logged.append(self.step)

    def send_blueprint(self, *args, **kwargs):
        pass

    def flush(self, timeout_sec=None):
        pass

    def disconnect(self):
        pass


def test_a_viewer_behind_rerun_drops_frames_instead_of_holding_the_run():
    # Given a viewer whose Rerun channel takes 0.3 s per frame
    sc = scene("tiny")
    rec = SlowRerun(0.3)
    v = Viewer(sc, ((0, 0, 0), (0.15, 0.2, 0.15)), rec, world=1, particles=12)
    f = Framelet(0, 10, 20, np.full((3, 4, 3), 200, np.uint8), np.ones((3, 4), np.float32), np.arange(12).reshape(3, 4))
    stats = {"sim_time": 0.1, "particles": 12, "bytes_sent": 0, "stage_ms": {}, "kinetic_energy": 0.0,
             "max_density_deviation": 0.0, "wall_time": time.time()}
    # When frames come 10 times faster than that (a control line rides on frame 5)
    longest = 0.0
    for step in range(20):
        t = time.perf_counter()
        v.add(step, 0, f, dict(stats, controls=["pause"] if step == 5 else []))
        longest = max(longest, time.perf_counter() - t)
        time.sleep(0.03)
    v.close()
    # Then adding a frame never waited for Rerun, frames were dropped and counted, the newest shown
    assert longest < 0.1, longest
    assert v.dropped > 5 and v.frames + v.dropped == 20 and v.frames == len(rec.logged)
    assert rec.logged[-1] == 19 and rec.logged == sorted(rec.logged)
    assert v.summary()["dropped_frames"] == v.dropped


def test_the_viewer_follows_a_camera_switch_and_a_changed_setting(tmp_path):
    import dataclasses

    from sphcore.render import SceneRenderer
    from sphcore.scene import RenderCamera
    # Given a scene with a second camera, viewed from the default one
    sc = scene("tiny")
    sc = dataclasses.replace(sc, render=dataclasses.replace(sc.render, cameras=[
        RenderCamera(name="side", eye=(0.6, 0.1, 0.075), target=(0.075, 0.1, 0.075))]))
    box = ((0.0, 0.0, 0.0), (0.15, 0.2, 0.15))
    rec = open_recording("test", tmp_path / "r.rrd")
    v = Viewer(sc, box, rec, world=1, particles=12)
    empty = Framelet(0, 0, 0, np.zeros((0, 0, 3), np.uint8), np.zeros((0, 0), np.float32), np.zeros((0, 0), np.int64))
    stats = {"sim_time": 0.1, "particles": 12, "bytes_sent": 0, "stage_ms": {}, "kinetic_energy": 0.0,
             "max_density_deviation": 0.0, "wall_time": time.time(), "camera": "default", "color_by": "speed",
             "range": [0.0, 2.0]}
    v.add(1, 0, empty, stats)
    # When the peers switch camera, colour by density and change the viscosity (sph control)
    v.add(2, 0, empty, dict(stats, camera="side", color_by="density", range=[990.0, 1010.0],
                            controls=["camera side", "color_by density", "set sph.alpha = 0.5"]))
    v.close()
    del rec
    # Then the outline is drawn from the new camera, and the info, legend and events say what changed
    side = SceneRenderer(sc, *box)
    side.camera_name = "side"
    expected_side, expected_default = side.image([])[0], SceneRenderer(sc, *box).image([])[0]
    got = images(tmp_path / "r.rrd")
    assert np.abs(got[2].astype(int) - expected_side).mean() < 2.0
    assert np.abs(got[1].astype(int) - expected_default).mean() < 2.0
    assert np.abs(expected_side.astype(int) - expected_default).mean() > 2.0
    info = text_logs(tmp_path / "r.rrd", "/info")[-1]
    assert "alpha = 0.5" in info and "step 2: set sph.alpha = 0.5" in info
    assert text_logs(tmp_path / "r.rrd", "/legend")[-1].startswith("# Colour: density")
    assert "step 2: camera side" in text_logs(tmp_path / "r.rrd", "/events")


def test_the_shipped_dam_break_has_named_cameras_that_frame_the_fluid_and_the_viewer_follows_one(tmp_path):
    from nodes.frames import domain_box
    from sphcore.render import BACKGROUND, SceneRenderer
    from sphcore.solver import Simulation
    # Given the 3D dam break as shipped (coarse) and its particles at t = 0
    sc = scene("dam_break", "particles.spacing=0.04")
    assert [c.name for c in sc.render.cameras] == ["side", "downstream"]
    box = domain_box(sc)
    sim = Simulation(sc, "f64")
    s = sim.state
    n = s.n_owned
    # When each camera renders them
    pictures = {}
    for name in ("default", "side", "downstream"):
        r = SceneRenderer(sc, *box)
        r.camera_name = name
        frame = r.framelet(0, s.x[:n], s.v[:n], s.rho[:n], s.p[:n], s.id[:n])
        pictures[name] = (frame, r.image([frame])[0])
    # Then every view shows the column (a fair share of its pixels) and no two views are alike
    for name, (_, rgb) in pictures.items():
        fluid = np.any(rgb != np.asarray(BACKGROUND, np.uint8), axis=-1).mean()
        assert fluid > 0.02, (name, fluid)
    names = list(pictures)
    for i in range(3):
        for j in range(i + 1, 3):
            assert np.abs(pictures[names[i]][1].astype(int) - pictures[names[j]][1].astype(int)).mean() > 2.0
    # ... and a viewer told by the peers to switch to "side" logs the side view, outline included
    rec = open_recording("test", tmp_path / "r.rrd")
    v = Viewer(sc, box, rec, world=1, particles=n)
    stats = {"sim_time": 0.0, "particles": n, "bytes_sent": 0, "stage_ms": {}, "kinetic_energy": 0.0,
             "max_density_deviation": 0.0, "wall_time": time.time(), "camera": "default", "color_by": "speed",
             "range": [0.0, 3.0]}
    v.add(1, 0, pictures["default"][0], stats)
    v.add(2, 0, pictures["side"][0], dict(stats, camera="side", controls=["camera side"]))
    v.close()
    del rec
    got = images(tmp_path / "r.rrd")
    assert np.abs(got[1].astype(int) - pictures["default"][1]).mean() < 2.0  # JPEG's error only
    assert np.abs(got[2].astype(int) - pictures["side"][1]).mean() < 2.0


def test_obstacles_are_drawn_into_the_composite_by_depth():
    from nodes.frames import domain_box
    # Given the obstacle scene (a sphere in a tilted tank) and a framelet filling the screen
    sc = scene("obstacle", "particles.spacing=0.05")
    box = domain_box(sc)
    v = Viewer(sc, box, SlowRerun(0.0), world=1, particles=1)
    cam = v.renderer.camera
    centre = np.array([0.15, -0.12, 0.0])  # the sphere's centre in the tank frame ...
    from sphcore.boundaries import container_frame
    c, R = container_frame(sc)
    centre = c + R @ centre                # ... in the world
    eye, right, up, forward = cam.basis()
    rel = centre - eye
    px = int(0.5 * cam.width + (rel @ right) * cam.focal / (rel @ forward))
    py = int(0.5 * cam.height - (rel @ up) * cam.focal / (rel @ forward))
    distance = float(rel @ forward)

    def fluid_at(depth):
        return Framelet(0, 0, 0, np.full((cam.height, cam.width, 3), [250, 0, 0], np.uint8),
                        np.full((cam.height, cam.width), depth, np.float32),
                        np.arange(cam.width * cam.height).reshape(cam.height, cam.width))
    # When the fluid is behind the sphere, and when it is in front
    behind_rgb, behind_depth = v.image([fluid_at(distance + 1.0)])
    front_rgb, _ = v.image([fluid_at(distance - 0.2)])
    v.close()
    # Then the sphere hides the fluid behind it (at its front surface's depth), and fluid in front hides it
    assert behind_rgb[py, px, 0] < 250 and abs(int(behind_rgb[py, px, 1]) - int(behind_rgb[py, px, 2])) < 60
    assert abs(float(behind_depth[py, px]) - (distance - 0.08)) < 0.01
    assert front_rgb[py, px].tolist() == [250, 0, 0]
    assert (behind_rgb[..., 0] < 250).mean() > 0.003  # the sphere covers some pixels, not one


def test_peer_events_and_bytes_per_exchange_reach_the_recording_and_hostile_ones_do_not(tmp_path):
    # Given frames whose statistics carry a rebalance, a warning and bytes per exchange, and a frame
    # whose event list and byte counts are malformed (statistics come off the wire)
    sc = scene("tiny")
    box = ((0.0, 0.0, 0.0), (0.15, 0.2, 0.15))
    rec = open_recording("test", tmp_path / "r.rrd")
    v = Viewer(sc, box, rec, world=1, particles=12)
    empty = Framelet(0, 0, 0, np.zeros((0, 0, 3), np.uint8), np.zeros((0, 0), np.float32), np.zeros((0, 0), np.int64))
    stats = {"sim_time": 0.1, "particles": 12, "bytes_sent": 0, "stage_ms": {}, "kinetic_energy": 0.0,
             "max_density_deviation": 0.0, "wall_time": time.time()}
    v.add(1, 0, empty, dict(stats, events=[["INFO", "step 1: rebalanced, cuts now [[3], [], []]"],
                                          ["WARN", "leaks: 2 particles put back"]],
                            bytes_by_exchange={"positions": 4096, "fields": 1024}))
    v.add(2, 0, empty, dict(stats, events=[["DEBUG", "not a level"], "not a pair", ["INFO", 5]],
                            bytes_by_exchange={"../../x": 10, "fields": float("nan"), "reduce": -1, "ok": True}))
    v.close()
    del rec
    # Then the event log holds the peer's lines, marked with its rank, and nothing of the malformed ones
    logged = text_logs(tmp_path / "r.rrd", "/events")
    assert "peer 0: step 1: rebalanced, cuts now [[3], [], []]" in logged
    assert "peer 0: leaks: 2 particles put back" in logged
    assert not any("not a" in t for t in logged)
    # and the bytes per exchange are plotted per peer, only for the plain names with sane counts
    steps = entity_steps(tmp_path / "r.rrd")
    assert steps.get("/stats/exchange_mb/positions/peer0") == [1]
    assert steps.get("/stats/exchange_mb/fields/peer0") == [1]
    assert not [e for e in steps if e.startswith("/stats/exchange_mb/") and "fields" not in e and "positions" not in e]


def test_frame_statistics_carry_the_peers_events_and_exchange_bytes():
    from nodes.frames import MAX_EVENTS, FrameMaker, domain_box
    from sphcore.solver import Simulation
    sc = scene("tiny")
    sim = Simulation(sc, "f64")
    maker = FrameMaker(sc, domain_box(sc), 0, 1, sim.n_particles)
    maker.exchange_bytes = {"positions": 10}
    for k in range(MAX_EVENTS + 3):
        maker.event("WARN", f"w{k}")
    _, stats, _, _ = maker.make(sim)
    assert stats["bytes_by_exchange"] == {"positions": 10}
    assert len(stats["events"]) == MAX_EVENTS + 1 and stats["events"][-1][1].startswith("3 more events")
    _, stats, _, _ = maker.make(sim)
    assert stats["events"] == []
