"""Checkpoints: resume == continuous (bitwise, f64), single process and peers (also with another
number of peers); corrupt, incomplete or mismatched checkpoints are refused with a clear message."""
import hashlib
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from launch.cli import main
from sphcore.checkpoint import scene_digest

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


# -- hostile checkpoints: each refused with one line naming the file, the value and what is allowed --
TINY = str(ROOT / "configs" / "tiny.toml")
LOG_LINE = re.compile(r"^\d\d:\d\d:\d\d \S+ (DEBUG|INFO|WARNING) ")  # logging's lines


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """tiny.toml run 2 steps, checkpointed at step 2: OUT/checkpoints/step_00000002."""
    out = tmp_path_factory.mktemp("tiny") / "run"
    assert main(["run", TINY, "--steps", "2", "--checkpoint-every", "2", "--out", str(out), "--quiet",
                 "--no-viewer"]) == 0
    return out


@pytest.fixture
def tiny(tiny_run, tmp_path):
    """A copy of tiny_run's output folder, to damage."""
    shutil.copytree(tiny_run, tmp_path / "run")
    return tmp_path / "run"


def one_error_line(err: str, *fragments):
    """Exactly one line besides the log lines: sph run's error, naming every fragment."""
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.strip() and not LOG_LINE.match(line)]
    assert len(lines) == 1 and lines[0].startswith("sph run: error: "), err
    for fragment in fragments:
        assert fragment in lines[0], f"{fragment!r} missing from {lines[0]!r}"


def resume_tiny(out: Path, tmp_path: Path) -> int:
    return main(["run", "--resume", str(out), "--steps", "3", "--out", str(tmp_path / "resumed"), "--quiet",
                 "--no-viewer"])


def damage(out: Path, arrays=None, manifest=None):
    """Change step 2's part (arrays(dict) -> dict) and manifest (manifest(dict) -> dict), with the
    checksums recomputed: a consistent checkpoint whose content is wrong."""
    folder = out / "checkpoints" / "step_00000002"
    doc = json.loads((folder / "manifest.json").read_text())
    if arrays is not None:
        part = folder / "peer_0000.npz"
        with np.load(part) as z:
            data = arrays({k: z[k] for k in z.files})
        np.savez(part, **data)
        doc["parts"][0]["sha256"] = hashlib.sha256(part.read_bytes()).hexdigest()
    if manifest is not None:
        doc = manifest(doc)
        doc["scene_sha256"] = scene_digest(doc["scene"])
    (folder / "manifest.json").write_text(json.dumps(doc))


@pytest.mark.parametrize("content, fragments", [
    (b"\xff\xfe\x00garbage", ["latest: not text", "byte 0xff at offset 0 is not UTF-8"]),
    (b"../../../etc\n", ["latest: holds \"../../../etc\"", "e.g. step_00000300"]),
], ids=["binary", "a-path"])
def test_a_latest_file_that_names_no_checkpoint_folder_is_refused_naming_it(tiny, tmp_path, capsys, content,
                                                                             fragments):
    (tiny / "checkpoints" / "latest").write_bytes(content)
    assert resume_tiny(tiny, tmp_path) == 2
    one_error_line(capsys.readouterr().err, str(tiny / "checkpoints" / "latest"), *fragments)
    assert not (tmp_path / "resumed").exists()


def test_an_extra_array_the_run_does_not_carry_is_refused(tiny, tmp_path, capsys):
    # Given tiny's checkpoint (its run carries one extra array, the lists' reference positions) with an
    # extra_bogus array added
    damage(tiny, arrays=lambda a: dict(a, extra_bogus=np.zeros((len(a["id"]), 7))))
    # Then resuming from it is refused before the first step, naming the array
    assert resume_tiny(tiny, tmp_path) == 2
    one_error_line(capsys.readouterr().err, "'extra_bogus': this run carries no such array",
                   "the extra arrays it carries: extra_x_ref")
    assert not (tmp_path / "resumed").exists()


def test_reference_positions_of_another_shape_are_refused(tiny, tmp_path, capsys):
    # Given tiny's checkpoint whose lists' reference positions hold one number per particle
    damage(tiny, arrays=lambda a: dict(a, extra_x_ref=a["extra_x_ref"][:, 0].copy()))
    # Then it is refused with its shape and the shape the run carries
    assert resume_tiny(tiny, tmp_path) == 2
    one_error_line(capsys.readouterr().err, "'extra_x_ref' is float64 (498,)", "this run carries it as float64 (498, 3)")
    assert not (tmp_path / "resumed").exists()


def test_reference_positions_far_from_the_particles_only_mean_a_build(tiny_run, tiny, tmp_path):
    # Given tiny's checkpoint whose lists' reference positions are 1 km off (checksum recomputed)
    damage(tiny, arrays=lambda a: dict(a, extra_x_ref=a["extra_x_ref"] + 1000.0))
    # Then the resumed run builds its lists from the particles' positions instead: the same neighbours,
    # so the result of the true checkpoint's resume to the rounding of another order of the sums
    assert resume_tiny(tiny, tmp_path) == 0
    assert main(["run", "--resume", str(tiny_run), "--steps", "3", "--out", str(tmp_path / "true"), "--quiet",
                 "--no-viewer"]) == 0
    a, b = final(tmp_path / "true"), final(tmp_path / "resumed")
    assert np.array_equal(a["id"], b["id"])
    assert np.allclose(a["x"], b["x"], rtol=0, atol=1e-12) and np.allclose(a["v"], b["v"], rtol=1e-9, atol=1e-12)


def test_an_extra_array_of_another_shape_is_refused_before_it_reaches_the_compiled_passes(tiny, tmp_path, capsys):
    # Given a checkpoint of a continuity-density run (it carries extra_density, one number per
    # particle) whose extra_density has 3 per particle
    def density_3d(a):
        return dict(a, extra_density=np.full((len(a["id"]), 3), 1000.0))

    def continuity(m):
        m["scene"]["sph"]["density"] = "continuity"
        return m
    damage(tiny, arrays=density_3d, manifest=continuity)
    # Then it is refused with its shape and the shape the run carries
    assert resume_tiny(tiny, tmp_path) == 2
    one_error_line(capsys.readouterr().err, "step_00000002: 'extra_density' is float64 (498, 3)",
                   "this run carries it as float64 (498,)")
    assert not (tmp_path / "resumed").exists()


@pytest.mark.parametrize("scale, fragments", [
    (None, ["'m' holds 5e-324", "masses must be normal float64 numbers (>= 2.225e-308 kg)"]),
    (1e-4, ["'m' holds 1.91243e-07 kg", "its scene's particles have 0.00191243 kg",
            "from 1.91243e-06 to 1.91243 kg are accepted"]),
    (1e4, ["'m' holds 19.1243 kg", "from 1.91243e-06 to 1.91243 kg are accepted"]),
], ids=["subnormal", "1e-4-times", "1e4-times"])
def test_masses_that_are_subnormal_or_far_from_the_scenes_are_refused(tiny, tmp_path, capsys, scale, fragments):
    # Given a checkpoint whose masses are positive but absurd (checksum recomputed)
    damage(tiny, arrays=lambda a: dict(a, m=np.full_like(a["m"], 5e-324) if scale is None else a["m"] * scale))
    # Then resuming is refused naming the mass and what is accepted (not a ZeroDivisionError in a step)
    assert resume_tiny(tiny, tmp_path) == 2
    one_error_line(capsys.readouterr().err, "step_00000002", *fragments)
    assert not (tmp_path / "resumed").exists()


def test_a_time_beyond_what_a_step_can_advance_is_refused(tiny, tmp_path, capsys):
    # Given a checkpoint at t = 1e20 s, where t + dt == t: a run --until 2e20 would never end
    damage(tiny, manifest=lambda m: dict(m, t=1e20))
    # Then it is refused naming t, its value and the range allowed (--steps: a run of the old code,
    # which took it, ends)
    assert resume_tiny(tiny, tmp_path) == 2
    one_error_line(capsys.readouterr().err, "step_00000002/manifest.json: t = 1e+20",
                   "expected a finite number in [0, 1e+09]")
    assert not (tmp_path / "resumed").exists()
