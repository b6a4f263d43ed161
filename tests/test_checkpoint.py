"""Checkpoints: resume == continuous (bitwise, f64), single process and peers (also with another
number of peers); corrupt, incomplete or mismatched checkpoints are refused with a clear message."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from launch.cli import main

ROOT = Path(__file__).resolve().parent.parent
DAM = str(ROOT / "configs" / "dam_break.toml")
SMALL = ["--set", "particles.spacing=0.05", "--no-viewer", "--quiet"]


def final(out):
    return np.load(Path(out) / "final.npz")


def assert_same(a, b):
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(a[key], b[key]), key


@pytest.fixture(scope="module", params=["symplectic_euler", "leapfrog"])
def continuous(request, tmp_path_factory):
    out = tmp_path_factory.mktemp("continuous")
    integrator = ["--set", f"time.integrator={request.param}"]
    assert main(["run", DAM, *SMALL, *integrator, "--steps", "90", "--out", str(out)]) == 0
    return integrator, out


def test_resume_equals_continuous_in_one_process(continuous, tmp_path):
    integrator, full = continuous
    # Given a run stopped at step 50 with checkpoints every 25 steps
    assert main(["run", DAM, *SMALL, *integrator, "--steps", "50", "--checkpoint-every", "25",
                 "--out", str(tmp_path / "a")]) == 0
    assert (tmp_path / "a" / "checkpoints" / "latest").read_text().strip() == "step_00000050"
    # When it is resumed to step 90
    assert main(["run", "--resume", str(tmp_path / "a"), "--steps", "90", "--no-viewer", "--quiet",
                 "--out", str(tmp_path / "b")]) == 0
    # Then the result is bitwise the uninterrupted run's
    assert_same(final(full), final(tmp_path / "b"))
    assert json.loads((tmp_path / "b" / "summary.json").read_text())["steps"] == 90


def test_two_peer_checkpoint_resumes_on_one_and_three_peers(continuous, tmp_path):
    integrator, full = continuous
    run = [sys.executable, "-m", "launch.cli", "run"]
    done = subprocess.run(run + [DAM, *SMALL, *integrator, "--peers", "2", "--steps", "50", "--checkpoint-every",
                                 "50", "--out", str(tmp_path / "a")], cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    parts = sorted(p.name for p in (tmp_path / "a" / "checkpoints" / "step_00000050").iterdir())
    assert parts == ["manifest.json", "peer_0000.npz", "peer_0001.npz"]
    for peers in (1, 3):
        out = tmp_path / f"b{peers}"
        done = subprocess.run(run + ["--resume", str(tmp_path / "a"), "--peers", str(peers), "--steps", "90",
                                     "--no-viewer", "--quiet", "--out", str(out)], cwd=ROOT, capture_output=True,
                              text=True)
        assert done.returncode == 0, done.stderr
        assert_same(final(full), final(out))


@pytest.fixture
def saved(tmp_path):
    assert main(["run", DAM, *SMALL, "--steps", "20", "--checkpoint-every", "10", "--out", str(tmp_path / "a")]) == 0
    return tmp_path / "a" / "checkpoints"


def resume(path, *extra):
    return main(["run", "--resume", str(path), "--steps", "30", "--no-viewer", "--quiet", *extra])


def test_a_corrupt_part_is_refused(saved, capsys):
    part = saved / "step_00000020" / "peer_0000.npz"
    data = bytearray(part.read_bytes())
    data[len(data) // 2] ^= 0xFF
    part.write_bytes(bytes(data))
    assert resume(saved.parent) == 2
    assert "peer_0000.npz is corrupt (checksum mismatch)" in capsys.readouterr().err


def test_a_missing_part_or_manifest_is_refused(saved, capsys):
    (saved / "step_00000020" / "peer_0000.npz").unlink()
    assert resume(saved.parent) == 2
    assert "part peer_0000.npz is missing" in capsys.readouterr().err
    (saved / "step_00000010" / "manifest.json").write_text("{not json")
    assert resume(saved / "step_00000010") == 2
    assert "manifest.json: unreadable" in capsys.readouterr().err


def test_an_interrupted_checkpoint_never_becomes_latest(saved, tmp_path):
    # a crash while writing step 30 leaves only its staging folder behind
    partial = saved / ".step_00000030.partial"
    partial.mkdir()
    (partial / "peer_0000.npz").write_bytes(b"half a file")
    assert (saved / "latest").read_text().strip() == "step_00000020"
    assert resume(saved.parent, "--out", str(tmp_path / "b")) == 0


def test_resume_refuses_a_scene_overrides_and_other_precision(saved, capsys):
    assert main(["run", DAM, "--resume", str(saved.parent), "--quiet"]) == 2
    assert "--resume uses the scene saved with the checkpoint" in capsys.readouterr().err
    assert resume(saved.parent, "--precision", "f32") == 2
    assert "the checkpoint is f64" in capsys.readouterr().err
    assert main(["run", "--resume", str(saved.parent.parent / "nothing"), "--quiet"]) == 2
    assert "no checkpoint here" in capsys.readouterr().err


def _real_manifest_with(**changes):
    """The real manifest with some fields changed (so that only they are wrong)."""
    def edit(text):
        return json.dumps(dict(json.loads(text), **changes))
    return edit


@pytest.mark.parametrize("manifest, fragment", [
    (lambda text: "[1, 2]", "format 'list'"),
    (lambda text: "[" * 100000 + "]" * 100000, "unreadable"),
    (lambda text: '{"format": "sphfluid-checkpoint-1"}', "step is missing"),
    (_real_manifest_with(parts=[{"file": "../../peer_0000.npz", "particles": 1, "sha256": "0"}]),
     "'parts' must list the parts"),
    (_real_manifest_with(parts=[{"file": "/etc/passwd", "particles": 1, "sha256": "0"}]),
     "'parts' must list the parts"),
], ids=["list", "nested", "only-format", "part-path-up", "part-path-absolute"])
def test_a_hostile_manifest_is_refused_without_reading_outside_the_checkpoint(saved, capsys, manifest, fragment):
    path = saved / "step_00000020" / "manifest.json"
    path.write_text(manifest(path.read_text()))
    assert resume(saved / "step_00000020") == 2
    err = capsys.readouterr().err
    assert fragment in err and "Traceback" not in err, err
