"""The viewer: recorded runs hold every entity for every rendered step; N peers' composite equals
one peer's image; incomplete frames are composited and marked."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from launch.cli import main
from nodes.recording import entity_steps, images, text_logs
from nodes.viewer import Viewer, frame_arrays, frame_from_arrays, open_recording
from sphcore.render import Framelet

from conftest import scene

ROOT = Path(__file__).resolve().parent.parent
DAM = ["--set", "particles.spacing=0.05", "--set", "render.every=20", "--set", "render.points_every=7",
       "--precision", "f64", "--steps", "60"]
PER_STEP = ["/composite/rgb", "/composite/depth", "/composite/peers", "/peers/0/rgb", "/fluid/points",
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
    assert (tmp_path / "viewer.json").exists()


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
    assert v.frames == 2 and v.incomplete == 1
    rec.flush()
    del rec, v
    assert text_logs(tmp_path / "r.rrd", "/composite/status") == [
        "step 5: incomplete frame, no framelet from peer(s) [1]"]
    assert images(tmp_path / "r.rrd")[7][20, 10].tolist() == [200, 200, 200]


def test_framelet_messages_round_trip_and_reject_mismatched_planes():
    f = Framelet(3, 1, 2, np.zeros((2, 5, 3), np.uint8), np.zeros((2, 5), np.float32), np.zeros((2, 5), np.int64))
    arrays = frame_arrays(f, {"a": 1}, np.zeros((4, 3)))
    g, stats, pts = frame_from_arrays(3, arrays)
    assert (g.x0, g.y0, g.w, g.h, stats, pts.shape) == (1, 2, 5, 2, {"a": 1}, (4, 3))
    arrays["rect"] = np.array([1, 2, 6, 2])
    with pytest.raises(ValueError, match="rectangle"):
        frame_from_arrays(3, arrays)


def test_a_viewer_joins_a_running_run_and_sees_the_same_frames(tmp_path):
    import re

    from test_peers import Lines, sph
    # Given a 2-peer run (with its own recording viewer)
    p = sph("run", "configs/dam_break.toml", "--peers", "2", "--steps", "900", "--out", str(tmp_path / "run"),
            "--set", "particles.spacing=0.04", "--set", "run.log_every=50", "--set", "render.every=50")
    log = Lines(p.stderr)
    log.wait_for("peer 0 sph.run INFO step 100", timeout=120)
    launch = next(line for line in log.lines if "endpoints" in line)
    run_id = re.search(r"run (\w+):", launch).group(1)
    endpoints = re.findall(r"(tls/[\d.]+:\d+)", launch)
    # When a second viewer joins by connecting to the peers' endpoints
    joined = subprocess.run([sys.executable, "-m", "launch.cli", "viewer", "configs/dam_break.toml", "--run-id",
                             run_id, *sum((["--connect", e] for e in endpoints), []), "--world", "2",
                             "--tls", str(tmp_path / "run" / "tls"), "--record",
                             str(tmp_path / "joined.rrd"), "--set", "particles.spacing=0.04",
                             "--set", "render.every=50", "--idle-timeout", "60"],
                            cwd=ROOT, capture_output=True, text=True, timeout=300)
    # Then the run is undisturbed, and the joined viewer recorded the later frames identically
    assert p.wait(timeout=300) == 0, log.text()
    assert joined.returncode == 0, joined.stderr
    mine, theirs = images(tmp_path / "joined.rrd"), images(tmp_path / "run" / "run.rrd")
    assert len(mine) >= 3 and max(mine) == 900 and min(mine) > 100
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
