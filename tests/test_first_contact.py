"""First contact (issue 21): a corpus of mistaken or hostile scenes and damaged checkpoints, each
written here in tmp_path. Every case goes through the real command line (``launch.cli.main``, and a
few through the installed ``sph`` script) and must exit 2 with one line that names the problem, no
traceback, and nothing written to the --out folder.
"""
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

from conftest import CONFIGS, ROOT

TINY = CONFIGS / "tiny.toml"
LOG_LINE = re.compile(r"^\d\d:\d\d:\d\d \S+ (DEBUG|INFO|WARNING) ")  # logging's lines (logging.basicConfig)


def assert_one_clear_line(err: str, command: str, fragments):
    """Exactly one error line from sph (any other line is a log line), naming every fragment."""
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.strip() and not LOG_LINE.match(line)]
    assert len(lines) == 1, err
    assert lines[0].startswith(f"sph {command}: error: "), err
    for fragment in fragments:
        assert fragment in lines[0], f"{fragment!r} missing from {lines[0]!r}"


def tiny_text(**replace) -> str:
    text = TINY.read_text()
    for old, new in replace.items():
        assert old in text, old
        text = text.replace(old, new)
    return text


def binary_stl(triangles: int) -> bytes:
    """A binary STL of ``triangles`` copies of one triangle."""
    tri = np.zeros(12, dtype="<f4")
    tri[3:12] = [0, 0, 0, 1, 0, 0, 0, 1, 0]
    return b"\0" * 80 + np.uint32(triangles).tobytes() + (tri.tobytes() + b"\0\0") * triangles


MESH_SCENE = tiny_text(**{"[domain]": '[[obstacles]]\nshape = "mesh"\nfile = "ring.stl"\ncenter = [0.075, 0.1, 0.075]\n'
                                     "scale = 0.05\n\n[domain]"})

# (id, file contents (str: text, bytes: raw), extra files {name: bytes}, --set overrides, fragments)
BAD_SCENES = [
    ("binary-file", b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR\xff\xfe", {}, [], ["not a text file", "not UTF-8"]),
    ("nul-byte", "[scene]\nname = \"a\0b\"\n", {}, [], ["not a text file", "NUL byte"]),
    ("nested-array", "x = " + "[" * 100000 + "]" * 100000 + "\n", {}, [], ["nested too deeply"]),
    ("not-toml", "[scene\nname = 1\n", {}, [], ["not valid TOML"]),
    ("empty-file", "", {}, [], ["fluid.blocks", "at least one"]),
    ("huge-file", "# " + "x" * (5 << 20) + "\n", {}, [], ["larger than 4 MiB"]),
    ("misspelled-key", tiny_text(**{"kernel = ": "kernal = "}), {}, [], ["sph.kernal", "did you mean 'kernel'"]),
    ("misspelled-section", tiny_text(**{"[forces]": "[forcse]"}), {}, [], ["[forcse]", "did you mean 'forces'"]),
    ("misspelled-choice", TINY.read_text(), {}, ["sph.kernel=wendland_c3"],
     ["sph.kernel", "wendland_c3", "did you mean 'wendland_c2'"]),
    ("too-many-particles", TINY.read_text(), {}, ["particles.spacing=1e-5", "particles.max_particles=10000000000"],
     ["particles.spacing = 1e-05", "particles", "particles.max_particles = 10000000000"]),
    ("more-memory-than-here", TINY.read_text(), {}, ["particles.spacing=5e-5",
                                                     "particles.max_particles=10000000000"],
     ["particles.spacing = 5e-05", "of memory", "available here"]),
    ("block-partly-outside", TINY.read_text(), {}, ["fluid.blocks[0].max=[0.3, 0.0375, 0.15]"],
     ["fluid.blocks[0]", "432 of its 864 particles fall outside", "clip = true"]),
    ("block-wholly-outside", TINY.read_text(), {}, ["fluid.blocks[1].center=[1.0, 1.0, 1.0]"],
     ["fluid.blocks[1]", "no particle of this block lies inside the domain"]),
    ("dim-3-to-2", TINY.read_text(), {}, ["scene.dim=2"], ["scene.dim=2", "written for 3D", "z component"]),
    ("dim-2-to-3", (CONFIGS / "dam_break_2d.toml").read_text(), {}, ["scene.dim=3"],
     ["scene.dim=3", "written for 2D", "3 components"]),
    ("override-nested", TINY.read_text(), {}, ["sph.alpha=" + "[" * 5000 + "]" * 5000], ["nested too deeply"]),
    ("stl-empty", MESH_SCENE, {"ring.stl": b""}, [], ["obstacles[0].file", "empty"]),
    ("stl-truncated", MESH_SCENE, {"ring.stl": binary_stl(20)[:300]}, [], ["obstacles[0].file"]),
    ("stl-no-triangles", MESH_SCENE, {"ring.stl": binary_stl(0)}, [], ["obstacles[0].file", "no triangles"]),
    ("stl-garbage", MESH_SCENE, {"ring.stl": b"solid x\n facet normal 0 0 1\n outer loop\n vertex 0 zero 0\n"},
     [], ["obstacles[0].file"]),
    ("mesh-other-suffix", MESH_SCENE.replace("ring.stl", "ring.txt"), {"ring.txt": b"0 0 0"}, [],
     ["obstacles[0].file", "must end in .stl"]),
]


def write_scene(tmp_path, contents, files) -> Path:
    path = tmp_path / "scene.toml"
    path.write_bytes(contents if isinstance(contents, bytes) else contents.encode())
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    return path


@pytest.mark.fast
@pytest.mark.parametrize("contents,files,overrides,fragments", [c[1:] for c in BAD_SCENES],
                         ids=[c[0] for c in BAD_SCENES])
@pytest.mark.parametrize("command", ["run", "scene"])
def test_a_bad_scene_is_one_line_exit_2_and_nothing_written(command, contents, files, overrides, fragments,
                                                            tmp_path, capsys):
    # Given a scene file (and its mesh) written here, and an output folder that does not exist
    path = write_scene(tmp_path, contents, files)
    out = tmp_path / "out"
    sets = sum((["--set", o] for o in overrides), [])
    # When sph run (or sph scene, which checks exactly what sph run checks) is given it
    argv = [command, str(path), *sets] + (["--steps", "1", "--out", str(out), "--quiet", "--no-viewer"]
                                          if command == "run" else [])
    rc = main(argv)
    # Then: exit 2, one line naming the problem, nothing written
    cap = capsys.readouterr()
    assert rc == 2, cap.err
    assert_one_clear_line(cap.err, command, fragments)
    assert cap.out == ""
    assert not out.exists()


@pytest.mark.fast
def test_clip_true_keeps_the_part_of_a_block_inside_the_domain(capsys):
    rc = main(["scene", str(TINY), "--set", "fluid.blocks[0].max=[0.3, 0.0375, 0.15]",
               "--set", "fluid.blocks[0].clip=true"])
    out = capsys.readouterr().out
    assert rc == 0
    assert "fluid.blocks[0] box    432 particles (clip = true)" in out  # the unclipped pool's 432


@pytest.mark.fast
@pytest.mark.parametrize("out,fragments", [
    ("/etc/passwd/x", ["--out '/etc/passwd/x'", "/etc/passwd is a file"]),
    ("/proc/sph-out", ["--out '/proc/sph-out'", "cannot write there"]),
])
def test_an_unwritable_output_folder_fails_before_the_first_step(out, fragments, capsys):
    rc = main(["run", str(TINY), "--steps", "100000", "--out", out, "--quiet", "--no-viewer"])
    err = capsys.readouterr().err
    assert rc == 2
    assert_one_clear_line(err, "run", fragments)
    assert "step" not in err.split("error:", 1)[1]  # it stopped before stepping


@pytest.mark.fast
@pytest.mark.parametrize("case", ["binary-file", "nested-array", "stl-truncated"])
def test_the_console_script_prints_only_the_one_line(case, tmp_path):
    _, contents, files, overrides, fragments = next(c for c in BAD_SCENES if c[0] == case)
    path = write_scene(tmp_path, contents, files)
    sph = Path(sys.executable).with_name("sph")
    proc = subprocess.run([str(sph), "run", str(path), "--out", str(tmp_path / "out"), "--quiet"], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith("sph run: error: "), proc.stderr
    assert not (tmp_path / "out").exists()


# ---------------------------------------------------------------------------------------------
# Damaged checkpoints
# ---------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def good_checkpoint(tmp_path_factory):
    """tiny.toml run 2 steps with a checkpoint at each: OUT/checkpoints/step_00000002."""
    out = tmp_path_factory.mktemp("ckpt") / "run"
    assert main(["run", str(TINY), "--steps", "2", "--checkpoint-every", "1", "--out", str(out), "--quiet",
                 "--no-viewer"]) == 0
    return out / "checkpoints" / "step_00000002"


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _rewrite_part(folder: Path, manifest: dict, change):
    """Rewrite peer_0000.npz with change(arrays) and put its new checksum into the manifest."""
    part = folder / "peer_0000.npz"
    with np.load(part) as z:
        arrays = {k: z[k] for k in z.files}
    data = change(arrays)
    if isinstance(data, bytes):
        part.write_bytes(data)
    else:
        np.savez(part, **data)
    manifest["parts"][0]["sha256"] = _sha(part)


def _edit_scene(manifest: dict, section: str, key: str, value, rehash: bool):
    manifest["scene"][section][key] = value
    if rehash:  # a consistent manifest whose scene does not fit its particles
        manifest["scene_sha256"] = scene_digest(manifest["scene"])


def _without(key):
    return lambda a: {k: v for k, v in a.items() if k != key}


# (id, edit(folder, manifest) -> the manifest to write (or a str: raw text), fragments)
BAD_CHECKPOINTS = [
    ("parts-missing", lambda f, m: {k: v for k, v in m.items() if k != "parts"}, ["'parts' must list"]),
    ("parts-empty", lambda f, m: dict(m, parts=[]), ["'parts' must list"]),
    ("part-outside", lambda f, m: dict(m, parts=[dict(m["parts"][0], file="../../../peer_0000.npz")]),
     ["'parts' must list"]),
    ("part-listed-twice", lambda f, m: dict(m, parts=m["parts"] * 2), ["a part twice"]),
    ("part-count-string", lambda f, m: dict(m, parts=[dict(m["parts"][0], particles="498")]), ["'parts' must list"]),
    ("precision-f16", lambda f, m: dict(m, precision="f16"), ["precision = \"f16\"", "'f32' or 'f64'"]),
    ("step-abc", lambda f, m: dict(m, step="abc"), ["step = \"abc\"", "an integer >= 0"]),
    ("step-negative", lambda f, m: dict(m, step=-100), ["step = -100", "an integer >= 0"]),
    ("step-float", lambda f, m: dict(m, step=2.5), ["step = 2.5", "an integer >= 0"]),
    ("step-bool", lambda f, m: dict(m, step=True), ["step = true", "an integer >= 0"]),
    ("dt-missing", lambda f, m: {k: v for k, v in m.items() if k != "dt"}, ["dt is missing"]),
    ("dt-zero", lambda f, m: dict(m, dt=0), ["dt = 0", "(0, 1]"]),
    ("dt-huge", lambda f, m: dict(m, dt=1e9), ["dt = 1000000000.0", "(0, 1]"]),
    ("t-nan", lambda f, m: json.dumps(m).replace(f'"t": {json.dumps(m["t"])}', '"t": NaN'), ["t = NaN", "finite"]),
    ("t-negative", lambda f, m: dict(m, t=-1.0), ["t = -1.0", "finite number"]),
    ("particles-zero", lambda f, m: dict(m, particles=0), ["particles = 0", "an integer >= 1"]),
    ("leaks-negative", lambda f, m: dict(m, leaks=-1), ["leaks = -1"]),
    ("limit-counts-unknown", lambda f, m: dict(m, limit_counts={"warp": 1}), ["limit_counts", "limit names"]),
    ("scene-not-object", lambda f, m: dict(m, scene=[1]), ["scene = [1]", "an object"]),
    ("manifest-list", lambda f, m: "[1, 2]", ["format 'list'"]),
    ("manifest-nested", lambda f, m: "[" * 100000 + "]" * 100000, ["unreadable"]),
    ("manifest-not-json", lambda f, m: "{not json", ["unreadable"]),
    ("format-other", lambda f, m: dict(m, format="sphfluid-checkpoint-0"), ["format 'sphfluid-checkpoint-0'"]),
    ("gravity-edited", lambda f, m: _edit_scene(m, "forces", "gravity", [0.0, -1.0, 0.0], False) or m,
     ["does not match its scene_sha256"]),
    ("scene-checksum-missing", lambda f, m: {k: v for k, v in m.items() if k != "scene_sha256"},
     ["scene_sha256 is missing"]),
    ("scene-other-particles", lambda f, m: _edit_scene(m, "particles", "spacing", 0.02, True) or m,
     ["its particles do not match its scene", "holds 498 particles"]),
    ("scene-invalid", lambda f, m: _edit_scene(m, "sph", "kernel", "gaussian", True) or m,
     ["its scene", "sph.kernel", "gaussian"]),
    ("part-count-wrong", lambda f, m: dict(m, parts=[dict(m["parts"][0], particles=497)]),
     ["holds 498 particles, the manifest says 497"]),
    ("particles-wrong", lambda f, m: dict(m, particles=499), ["the run had 499"]),
    ("part-corrupt", lambda f, m: (f / "peer_0000.npz").write_bytes(b"PK\x03\x04" + b"\0" * 100) and m,
     ["corrupt (checksum mismatch)"]),
    ("part-missing", lambda f, m: (f / "peer_0000.npz").unlink() or m, ["part peer_0000.npz is missing"]),
    ("part-truncated", lambda f, m: _rewrite_part(f, m, lambda a: (f / "peer_0000.npz").read_bytes()[:200]) or m,
     ["peer_0000.npz is unreadable"]),
    ("part-without-x", lambda f, m: _rewrite_part(f, m, _without("x")) or m, ["has no 'x' array"]),
    ("part-x-nan", lambda f, m: _rewrite_part(f, m, lambda a: dict(a, x=np.full_like(a["x"], np.nan))) or m,
     ["'x' holds non-finite values"]),
    ("part-x-f32", lambda f, m: _rewrite_part(f, m, lambda a: dict(a, x=a["x"].astype(np.float32))) or m,
     ["'x' is float32", "expected float64"]),
    ("part-x-flat", lambda f, m: _rewrite_part(f, m, lambda a: dict(a, x=a["x"][:, :2].copy())) or m,
     ["'x' is float64 (498, 2)"]),
    ("part-mass-zero", lambda f, m: _rewrite_part(f, m, lambda a: dict(a, m=np.zeros_like(a["m"]))) or m,
     ["masses <= 0"]),
    ("part-pickled", lambda f, m: _rewrite_part(f, m, lambda a: dict(a, x=np.array([object()] * 3))) or m,
     ["peer_0000.npz is unreadable"]),
]


@pytest.mark.fast
@pytest.mark.parametrize("edit,fragments", [c[1:] for c in BAD_CHECKPOINTS], ids=[c[0] for c in BAD_CHECKPOINTS])
def test_a_damaged_checkpoint_is_one_line_exit_2_and_nothing_written(good_checkpoint, edit, fragments, tmp_path,
                                                                     capsys):
    # Given a copy of a good checkpoint, damaged in one way
    folder = tmp_path / "step_00000002"
    shutil.copytree(good_checkpoint, folder)
    manifest = json.loads((folder / "manifest.json").read_text())
    damaged = edit(folder, manifest)
    (folder / "manifest.json").write_text(damaged if isinstance(damaged, str) else json.dumps(damaged))
    out = tmp_path / "out"
    # When a run resumes from it
    rc = main(["run", "--resume", str(folder), "--steps", "5", "--out", str(out), "--quiet", "--no-viewer"])
    # Then: exit 2, one line naming the problem, nothing written
    err = capsys.readouterr().err
    assert rc == 2, err
    assert_one_clear_line(err, "run", fragments)
    assert not out.exists()


@pytest.mark.fast
def test_the_good_checkpoint_of_the_corpus_resumes(good_checkpoint, tmp_path):
    # (so that every refusal above is the damage's, not the checkpoint's)
    folder = tmp_path / "step_00000002"
    shutil.copytree(good_checkpoint, folder)
    out = tmp_path / "out"
    assert main(["run", "--resume", str(folder), "--steps", "3", "--out", str(out), "--quiet", "--no-viewer"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["steps"] == 3 and summary["status"] == "complete"


# ---------------------------------------------------------------------------------------------
# A run keeps what it did: summary.json from the start, the outputs on SIGTERM / Ctrl-C
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("signal_name", ["SIGTERM", "SIGINT"])
def test_a_stopped_run_writes_its_outputs_marked_interrupted_with_the_step(signal_name, tmp_path):
    import os
    import signal
    import time
    # Given a long run of tiny.toml
    out = tmp_path / "out"
    sph = Path(sys.executable).with_name("sph")
    proc = subprocess.Popen([str(sph), "run", str(TINY), "--steps", "10000000", "--out", str(out), "--no-viewer",
                             "--quiet"], cwd=ROOT, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, NUMBA_NUM_THREADS="1"))
    try:
        # When summary.json says it is running (written before the first step) and then it is stopped
        deadline = time.monotonic() + 240
        while not (out / "summary.json").exists():
            assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read() if proc.poll() else ""
            time.sleep(0.2)
        assert json.loads((out / "summary.json").read_text())["status"] == "running"
        time.sleep(3)  # past the first (compiling) step
        proc.send_signal(getattr(signal, signal_name))
        err = proc.communicate(timeout=120)[1]
    finally:
        if proc.poll() is None:
            proc.kill()
    # Then it exits 130 with the outputs of the step it stopped at, marked interrupted
    assert proc.returncode == 130, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted"
    assert summary["interrupted"] == {"signal": signal_name, "step": summary["steps"]}
    assert 0 < summary["steps"] < 10000000
    with np.load(out / "final.npz") as f:
        assert int(f["interrupted_step"]) == summary["steps"]
        assert len(f["id"]) == summary["particles"] == 498
    assert (out / "scene.toml").is_file()
    assert "Traceback" not in err and f"interrupted ({signal_name}) at step {summary['steps']}" in err


@pytest.mark.fast
def test_the_tutorial_scene_checks_as_the_tutorial_says(capsys):
    # docs/TUTORIAL.md quotes this summary and this error
    assert main(["scene", str(ROOT / "docs" / "tutorial" / "splash.toml")]) == 0
    out = capsys.readouterr().out
    assert "fluid.blocks[0] box    600 particles" in out and "particles     680 " in out
    assert main(["scene", str(ROOT / "docs" / "tutorial" / "splash.toml"), "--set",
                 "fluid.blocks[0].max=[0.8, 0.1]"]) == 2
    assert "200 of its 800 particles fall outside the domain" in capsys.readouterr().err


def test_summary_json_is_rewritten_while_the_run_goes_on(tmp_path, monkeypatch):
    # Given a one-process run that rewrites its summary after every step (summary_every_s = 0)
    from nodes import driver
    from nodes.transport import InProcessNetwork
    from sphcore.halo import NULL_HALO
    from sphcore.scene import load_scene
    from sphcore.solver import Simulation
    written = []
    real = driver.write_summary

    def record(path, summary):
        real(path, summary)  # the atomic write of sphcore/output.py
        written.append((summary["status"], summary["steps"], json.loads(path.read_text())["status"]))

    monkeypatch.setattr(driver, "write_summary", record)
    scene = load_scene(TINY)
    sim = Simulation(scene, "f64")
    peer = driver.PeerRun(sim, scene, NULL_HALO, InProcessNetwork().endpoint(0))
    plan = driver.RunPlan(steps=3, out=tmp_path / "out", progress=False, summary_every_s=0.0)
    # When it runs 3 steps
    summary = driver.run_blocking(driver.drive(peer, plan))
    # Then summary.json said "running" before the first step and after each, then "complete"
    assert written == [("running", 0, "running"), ("running", 1, "running"), ("running", 2, "running"),
                       ("running", 3, "running"), ("complete", 3, "complete")]
    assert summary["status"] == "complete"
    assert not list((tmp_path / "out").glob(".*"))  # no temporary or probe file left behind
