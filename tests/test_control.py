"""The control channel: commands reach every peer at the same step, pause holds the run (and what
is sent meanwhile applies at once), step N holds it again N steps later, every command is answered
(accepted at step N, or rejected with the reason), bad commands and announcements are refused, a
single-process run listens too (--control), and the recording shows what was applied. The
in-process checks of every command against resumed and fresh runs are in test_steering.py."""
import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from nodes import control
from nodes.recording import text_logs

from test_peers import Lines, sph

ROOT = Path(__file__).resolve().parent.parent


def send(run_id, endpoint, tls, *command) -> int:
    """``sph control`` with the run's controller certificate; the step at which it was accepted. It
    waits up to 150 s for rank 0 (the default 10 s was seen to run out on a loaded 2-core machine,
    where the peers' Zenoh threads wait for a core, and 60 s once in a suite started from an empty
    numba cache, 2026-12-06, while the other worker compiled every CUDA kernel)."""
    done = subprocess.run([sys.executable, "-m", "launch.cli", "control", "--run-id", run_id, "--zenoh", endpoint,
                           "--tls", str(tls), "--world", "2", "--timeout", "150", *command], cwd=ROOT,
                          capture_output=True, text=True, timeout=240)
    assert done.returncode == 0 and "sph control: accepted at step" in done.stderr, done.stderr
    return int(done.stderr.rsplit("accepted at step", 1)[1].split()[0])


def test_commands_apply_on_every_peer_at_the_same_step_and_are_recorded(tmp_path):
    # Given a 2-peer run with its viewer
    p = sph("run", "configs/dam_break.toml", "--peers", "2", "--steps", "1200", "--out", str(tmp_path),
            "--set", "particles.spacing=0.04", "--set", "run.log_every=50", "--set", "render.every=50")
    log = Lines(p.stderr)
    log.wait_for("peer 0 sph.run INFO step 100", timeout=120)
    launch = next(line for line in log.lines if "endpoints" in line)
    run_id = re.search(r"run (\w+):", launch).group(1)
    rank0 = re.search(r"endpoints (\w+/[\d.]+:\d+)", launch).group(1)
    tls = tmp_path / "tls"
    # When a controller pauses it, changes the external force while paused, switches the colours,
    # writes a checkpoint, steps 5 steps, resets the fluid while held again and resumes
    paused = send(run_id, rank0, tls, "pause")
    log.wait_for("peer 1: step", timeout=30)
    time.sleep(0.5)
    steps_before = sum("sph.run INFO step" in line for line in log.lines)
    time.sleep(1.0)
    assert sum("sph.run INFO step" in line for line in log.lines) == steps_before  # held
    held = [send(run_id, rank0, tls, "set", "forces.external=[2.0, 0.0, 0.0]"),
            send(run_id, rank0, tls, "color_by", "rank"), send(run_id, rank0, tls, "checkpoint")]
    assert held == [paused] * 3  # applied at once, on every peer, at the held step
    assert send(run_id, rank0, tls, "step", "5") == paused + 5
    log.wait_for(f"peer 1: step {paused + 5}: pause", timeout=60)
    assert send(run_id, rank0, tls, "reset") == paused + 5
    assert send(run_id, rank0, tls, "resume") == paused + 5
    assert p.wait(timeout=300) == 0, log.text()
    # Then both peers applied the same commands after the same steps, and the recording lists them
    s = json.loads((tmp_path / "summary.json").read_text())
    applied = [c for c in s["per_peer"][0]["controls"]]
    assert applied == s["per_peer"][1]["controls"] == s["controls"]
    assert applied == [[paused, "pause"], [paused, "set forces.external = [2.0, 0.0, 0.0]"],
                       [paused, "color_by rank"], [paused, "checkpoint"], [paused + 5, "pause"],
                       [paused + 5, "reset"]]
    assert s["steps"] == 1200
    assert json.loads((tmp_path / "checkpoints" / f"step_{paused:08d}" / "manifest.json").read_text())[
        "scene"]["forces"]["external"] == [2.0, 0.0, 0.0]
    logged = text_logs(tmp_path / "run.rrd", "/control")
    assert "pause" in logged and "set forces.external = [2.0, 0.0, 0.0]" in logged and "reset" in logged


def control_of(out, *words):
    """``sph control OUT WORDS``: (exit code, what it printed, the step it was accepted at or None)."""
    done = subprocess.run([sys.executable, "-m", "launch.cli", "control", str(out), *words], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)
    step = re.search(r"accepted at step (\d+)", done.stderr)
    return done.returncode, done.stderr, int(step.group(1)) if step else None


def test_a_single_process_run_listens_for_every_command(tmp_path, capsys):
    # Given a one-process run that listens (--control) and would run for a long time
    from launch.cli import main
    from sphcore import checkpoint
    from sphcore.scene import live_change, scene_from_dict
    from test_steering import assert_same, run_one
    from conftest import scene
    out = tmp_path / "run"
    p = sph("run", "configs/tiny.toml", "--control", "--steps", "1000000", "--out", out, "--no-viewer", "--quiet")
    log = Lines(p.stderr)
    try:
        log.wait_for("listening for sph control", timeout=120, proc=p)
        # When a controller pauses it, sets a key, writes a checkpoint, tries two keys it cannot
        # change, steps 5 steps, resets it while held again, and stops it (SIGINT)
        rc, err, k = control_of(out, "pause")
        assert rc == 0 and k is not None, err
        assert control_of(out, "set", "forces.external=[1.0, 0.0, 0.0]")[::2] == (0, k)
        assert control_of(out, "checkpoint")[::2] == (0, k)
        rc, err, _ = control_of(out, "set", "sph.kernel=cubic_spline")
        assert rc == 2 and "sph.kernel" in err and "compiled step" in err and "Traceback" not in err, err
        rc, err, _ = control_of(out, "set", "time.steps=5")
        assert rc == 2 and "time.steps" in err and "run's length" in err and "Traceback" not in err, err
        assert control_of(out, "step", "5")[::2] == (0, k + 5)
        log.wait_for(f"step {k + 5}: pause", timeout=60, proc=p)
        held = json.loads((out / "summary.json").read_text())  # rewritten when the run is held
        assert held["status"] == "paused" and held["steps"] == k + 5 and held["controls"][-1] == [k + 5, "pause"]
        assert control_of(out, "reset")[::2] == (0, k + 5)
        p.send_signal(signal.SIGINT)
        assert p.wait(timeout=60) == 130, log.text()
    finally:
        p.kill()
    # Then everything applied is in summary.json, and the outputs are of the reset state
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "interrupted" and s["steps"] == k + 5 and s["sim_time"] == 0.0
    assert s["controls"] == [[k, "pause"], [k, "set forces.external = [1.0, 0.0, 0.0]"], [k, "checkpoint"],
                             [k + 5, "pause"], [k + 5, "reset"]]
    from sphcore.solver import Simulation
    initial = Simulation(scene("tiny"), "f64").final_arrays()
    assert np.array_equal(np.load(out / "final.npz")["x"], initial["x"])
    # And the checkpoint of step k resumes with another key set (--resume DIR --set KEY=VALUE) as the
    # run driver resumes it in this process
    ckpt = checkpoint.load(out / "checkpoints")
    assert ckpt.manifest["step"] == k and ckpt.manifest["scene"]["forces"]["external"] == [1.0, 0.0, 0.0]
    assert main(["run", "--resume", str(out / "checkpoints"), "--set", "sph.alpha=0.1", "--steps", str(k + 4),
                 "--out", str(tmp_path / "resumed"), "--no-viewer", "--quiet"]) == 0
    _, changed = live_change(scene_from_dict(ckpt.manifest["scene"]), "sph.alpha=0.1")
    _, reference, _ = run_one(changed, tmp_path / "reference", steps=k + 4, resume=ckpt)
    assert_same(dict(np.load(tmp_path / "resumed" / "final.npz")), reference)
    # And a key that cannot change during a run cannot change in a resumed run either: one line, exit 2
    capsys.readouterr()
    assert main(["run", "--resume", str(out / "checkpoints"), "--set", "particles.spacing=0.01",
                 "--out", str(tmp_path / "refused"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "particles.spacing cannot change during a run" in err and "particle set" in err and "\n" not in err, err


@pytest.mark.fast
@pytest.mark.parametrize("text, fragment", [
    ("jump", "unknown command"),
    ("", "empty command"),
    ("set sph.kernel=muller", "not settable at run time: it changes the compiled step"),
    ("set particles.spacing=0.01", "not settable at run time: it changes the particle set"),
    ("set time.steps=5", "not settable at run time: it fixes the run's length"),
    ("set render.width=10", "not settable at run time: it is read by the viewer"),
    ("set fluid.blocks[0].velocity=[1,0,0]", "not settable at run time: it changes the particle set"),
    ("set sph.alhpa=0.1", "did you mean 'alpha'"),
    ("set sph.alpha[0]=0.3", "[0] after 'sph.alpha', which is not an array of tables"),
    ("set fluid.blocks[0][1].min=1", "[1] after 'fluid.blocks', which is not an array of tables"),
    ("set nosuch.key=1", "unknown section"),
    ("set sph.alpha", "expected set KEY=VALUE"),
    ("color_by temperature", "color_by 'temperature': allowed speed"),
    ("step", "expected a number of steps"),
    ("step 0", "expected a number of steps"),
    ("step -3", "expected a number of steps"),
    ("step 1e3", "expected a number of steps"),
    ("step 99999999999", "expected a number of steps"),
    ("pause now", "pause takes no argument"),
    ("reset all", "reset takes no argument"),
])
def test_bad_commands_are_refused_with_the_allowed_ones(text, fragment):
    with pytest.raises(ValueError, match=re.escape(fragment)):
        control.parse(text)


@pytest.mark.fast
def test_values_go_through_the_scene_validation():
    from conftest import scene
    sc = scene("tiny")
    ok, after = control.validate(sc, control.parse("set sph.alpha=0.1"), ["default"])
    assert ok["value"] == 0.1 and after.sph.alpha == 0.1 and sc.sph.alpha != 0.1
    ok, _ = control.validate(sc, control.parse("set forces.external=[1, 0, 0]"), ["default"])
    assert ok["value"] == [1.0, 0.0, 0.0]
    with pytest.raises(ValueError, match="sph.alpha"):
        control.validate(sc, control.parse("set sph.alpha=-1"), ["default"])
    with pytest.raises(ValueError, match="3 components"):
        control.validate(sc, control.parse("set forces.external=[1, 0]"), ["default"])
    with pytest.raises(ValueError, match="camera 'top'"):
        control.validate(sc, control.parse("camera top"), ["default"])
    with pytest.raises(ValueError, match="no output folder"):
        control.validate(sc, control.parse("checkpoint"), ["default"], can_checkpoint=False)


@pytest.mark.fast
@pytest.mark.parametrize("commands, fragment", [
    ({"op": "pause"}, "not a list"),
    ([{"op": "resume"}], "not one of"),
    ([{"op": "step", "count": 3}], "not one of"),
    ([{"op": "reset", "extra": 1}], "with its fields"),
    (["pause"], "not one of"),
    ([{"op": "set", "key": "sph.kernel", "value": "muller"}], "not settable"),
    ([{"op": "set", "key": ["sph.alpha"], "value": 0.1}], "not settable"),
    ([{"op": "set", "key": "sph.alpha", "value": {"a": 1}}], "not a scene value"),
    ([{"op": "set", "key": "sph.alpha", "value": 99.0}], "allowed range"),
    ([{"op": "set", "key": "sph.alpha", "value": "0.1"}], "not a validated value"),
    ([{"op": "color_by", "quantity": "heat"}], "allowed"),
    ([{"op": "camera", "name": 3}], "not a name"),
])
def test_announced_commands_that_rank_0_could_not_have_sent_are_refused(commands, fragment):
    from conftest import scene
    with pytest.raises(ValueError, match=fragment):
        control.check_announced(scene("tiny"), commands, ["default"])


@pytest.mark.fast
def test_announced_sets_are_checked_in_order_and_against_the_running_step():
    from conftest import scene
    from sphcore.solver import Simulation
    sc = scene("tiny", "sph.viscosity=muller", "sph.nu=1e-5")
    sim = Simulation(sc, "f64")
    ok = [{"op": "set", "key": "sph.nu", "value": 2e-5}, {"op": "reset"}, {"op": "checkpoint"}]
    assert control.check_announced(sc, ok, ["default"], sim) == ok
    drag = [{"op": "set", "key": "terms.drag", "value": 1.0}]  # a stage switched on: a restart in place
    assert control.check_announced(sc, drag, ["default"], sim) == drag
    with pytest.raises(ValueError, match="needs nu > 0"):  # the scene's cross-key rules hold too
        control.check_announced(sc, [{"op": "set", "key": "sph.nu", "value": 0.0}], ["default"], sim)
