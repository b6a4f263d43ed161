"""The control channel: commands reach every peer at the same step, pause holds the run, every
command is answered (accepted at step N, or rejected with the reason), bad commands are refused,
and the recording shows what was applied."""
import json
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from nodes import control
from nodes.recording import text_logs

from test_peers import Lines, sph

ROOT = Path(__file__).resolve().parent.parent


def send(run_id, endpoint, tls, *command) -> int:
    """``sph control`` with the run's controller certificate; the step at which it was accepted."""
    done = subprocess.run([sys.executable, "-m", "launch.cli", "control", "--run-id", run_id, "--connect", endpoint,
                           "--tls", str(tls), "--world", "2", *command], cwd=ROOT, capture_output=True, text=True,
                          timeout=60)
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
    # When a controller pauses it, changes the external force while paused, switches the colours and resumes
    paused = send(run_id, rank0, tls, "pause")
    log.wait_for("peer 1: step", timeout=30)
    time.sleep(0.5)
    steps_before = sum("sph.run INFO step" in line for line in log.lines)
    time.sleep(1.0)
    assert sum("sph.run INFO step" in line for line in log.lines) == steps_before  # held
    held = [send(run_id, rank0, tls, "set", "forces.external=[2.0, 0.0, 0.0]"),
            send(run_id, rank0, tls, "color_by", "rank")]
    assert send(run_id, rank0, tls, "resume") == paused
    assert p.wait(timeout=300) == 0, log.text()
    # Then both peers applied the same commands after the same steps, and the recording lists them
    s = json.loads((tmp_path / "summary.json").read_text())
    applied = [c for c in s["per_peer"][0]["controls"]]
    assert applied == s["per_peer"][1]["controls"]
    texts = [t for _, t in applied]
    assert texts[0] == "pause" and sorted(texts[1:]) == ["color_by rank", "set forces.external = [2.0, 0.0, 0.0]"]
    assert applied[1][0] == applied[2][0] > applied[0][0]  # held commands go out together after resume
    assert [step for step, _ in applied] == [paused] + held  # each applied where its answer said
    assert s["steps"] == 1200
    logged = text_logs(tmp_path / "run.rrd", "/control")
    assert "pause" in logged and "set forces.external = [2.0, 0.0, 0.0]" in logged


@pytest.mark.parametrize("text, fragment", [
    ("jump", "unknown command"),
    ("set sph.kernel=muller", "not settable"),
    ("color_by temperature", "unknown command"),
])
def test_bad_commands_are_refused_with_the_allowed_ones(text, fragment):
    with pytest.raises(ValueError, match=fragment):
        control.parse(text)


def test_values_go_through_the_scene_validation():
    from conftest import scene
    sc = scene("tiny")
    ok = control.validate(sc, control.parse("set sph.alpha=0.1"), ["default"])
    assert ok["value"] == 0.1
    with pytest.raises(ValueError, match="sph.alpha"):
        control.validate(sc, control.parse("set sph.alpha=-1"), ["default"])
    with pytest.raises(ValueError, match="camera 'top'"):
        control.validate(sc, control.parse("camera top"), ["default"])
