"""Peer processes over Zenoh (loopback): `sph run --peers N` reproduces one process bit for bit,
and a peer that dies or a Ctrl-C stops the whole run quickly, never a hang."""
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from launch.cli import main

ROOT = Path(__file__).resolve().parent.parent
DAM = str(ROOT / "configs" / "dam_break.toml")
SMALL = ["--set", "particles.spacing=0.04", "--precision", "f64"]


def sph(*args, **kw):
    return subprocess.Popen([sys.executable, "-m", "launch.cli", *map(str, args)], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True, **kw)


def test_two_peer_processes_reproduce_one_process_bitwise_with_load_balancing(tmp_path):
    # Given the 3D dam break run in this process, and as 2 peer processes with cuts moved every 20 steps
    assert main(["run", DAM, *SMALL, "--steps", "150", "--out", str(tmp_path / "one"), "--quiet"]) == 0
    p = sph("run", DAM, *SMALL, "--steps", "150", "--out", str(tmp_path / "two"), "--peers", "2",
            "--set", "decomposition.balance_every=20", "--quiet")
    out, err = p.communicate(timeout=300)
    assert p.returncode == 0, err
    one, two = np.load(tmp_path / "one" / "final.npz"), np.load(tmp_path / "two" / "final.npz")
    # Then final.npz is bitwise identical, and the summary reports the peers' side of the run
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(one[key], two[key]), key
    s = json.loads((tmp_path / "two" / "summary.json").read_text())
    assert s["peers"] == 2 and s["particles"] == len(one["id"]) and s["steps"] == 150
    assert sum(p["particles_final"] for p in s["per_peer"]) == s["particles"]
    assert all(p["rebalances"] == 7 and p["dropped_messages"] == 0 for p in s["per_peer"])
    assert s["bytes_sent"] == sum(s["bytes_sent_per_phase"].values()) > 0
    assert {"migrants", "positions", "fields", "reduce", "balance", "migrate"} <= set(s["bytes_sent_per_phase"])
    assert 1.0 <= s["imbalance"]["particles_max_over_mean"]["mean"] < 2.0  # balancing moved particles over
    for peer in s["per_peer"]:
        assert peer["wait_s_total"] >= 0 and peer["compute_s_total"] > 0
        # and its waits per phase are those of the same timed steps (not the first, compiling one's)
        assert sum(peer["wait_s_per_phase"].values()) == pytest.approx(peer["wait_s_total"], rel=1e-9, abs=1e-9)


class Lines:
    """Collect a process's stderr lines in a thread; wait for one that matches."""

    def __init__(self, stream):
        self.lines, self.arrived = [], []
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream):
        for line in stream:
            self.lines.append(line)
            self.arrived.append(time.perf_counter())

    def wait_for(self, text, timeout, proc=None):
        """Until a line contains ``text``; gives up early when ``proc`` has ended."""
        deadline = time.time() + timeout
        while time.time() < deadline:
            if any(text in line for line in self.lines):
                return
            if proc is not None and proc.poll() is not None:
                break
            time.sleep(0.05)
        raise AssertionError(f"{text!r} not seen in {timeout} s:\n{''.join(self.lines)}")

    def first(self, text):
        """Arrival time (perf_counter) of the first line containing text."""
        return next(t for line, t in zip(self.lines, self.arrived) if text in line)

    def text(self):
        self._thread.join(5)
        return "".join(self.lines)


def _processes():
    """[(pid, its /proc stat fields after the command name, its command line)] of every process."""
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
                cmd = (entry / "cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            out.append((int(entry.name), fields, [c.decode() for c in cmd]))
    return out


def children(pid):
    return [(p, cmd) for p, fields, cmd in _processes() if int(fields[1]) == pid]


def _sigint_as_at_a_terminal():
    """In the child before exec: SIGINT handled by default and not blocked, as a shell's foreground
    job has it. A process started with SIGINT ignored keeps ignoring it (the POSIX convention for
    background jobs, which Python and sph follow); in three cold full-suite runs (2026-12-06) every
    process of this test's run ignored the Ctrl-C, as if the test worker had SIGINT ignored or
    blocked by then (not found which earlier test does that; alone the test passed every time)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def _sigint_state():
    """This process's SIGINT: its Python handler and whether the kernel has it ignored or blocked."""
    status = {k: v for k, v in (line.split(":", 1) for line in Path("/proc/self/status").read_text().splitlines())}
    bit = 1 << (signal.SIGINT - 1)
    return (f"handler {signal.getsignal(signal.SIGINT)}, ignored {bool(int(status['SigIgn'], 16) & bit)}, "
            f"blocked {bool(int(status['SigBlk'], 16) & bit)}")


def _group_processes(pgid):
    """[(pid, state, command)] of the processes in process group ``pgid``."""
    return [(p, fields[0], " ".join(cmd)[:160]) for p, fields, cmd in _processes() if int(fields[2]) == pgid]


@pytest.mark.parametrize("how", ["kill-9", "ctrl-c"])
def test_a_killed_peer_or_ctrl_c_stops_every_process_quickly(how, tmp_path):
    # Given a 2-peer run that would take minutes
    p = sph("run", DAM, *SMALL, "--steps", "100000", "--out", str(tmp_path / "o"), "--peers", "2",
            "--set", "run.log_every=20", preexec_fn=_sigint_as_at_a_terminal)
    log = Lines(p.stderr)
    log.wait_for("peer 0 sph.run INFO step", timeout=120)
    peers = {cmd[cmd.index("--rank") + 1]: pid for pid, cmd in children(p.pid) if "--rank" in cmd}
    assert set(peers) == {"0", "1"}
    # When peer 1 is killed (no goodbye), or Ctrl-C reaches the whole process group
    t0 = time.perf_counter()
    if how == "kill-9":
        os.kill(peers["1"], signal.SIGKILL)
    else:
        os.killpg(p.pid, signal.SIGINT)
    try:
        rc = p.wait(timeout=30)
    except subprocess.TimeoutExpired:  # say which processes were still there, and what they logged
        left = _group_processes(p.pid)
        os.killpg(p.pid, signal.SIGKILL)
        raise AssertionError(f"{how}: still running 30 s later: {left}; this process's SIGINT: {_sigint_state()}\n"
                             f"{log.text()[-6000:]}") from None
    elapsed = time.perf_counter() - t0
    err = log.text()
    # Then the launcher and every peer exit non-zero within seconds, saying why; nothing is written
    assert all(not Path(f"/proc/{pid}").exists() or "zombie" in Path(f"/proc/{pid}/status").read_text().lower()
               for pid in peers.values())
    if how == "kill-9":
        assert rc == 4, err
        assert "peer 1 was killed by signal 9" in err
        assert "peer 0" in err and "peer 1 left the run" in err
        # the launcher and peer 0 both said so within 2 s of the kill; all processes were gone within 5 s
        assert log.first("peer 1 was killed by signal 9") - t0 < 2.0
        assert log.first("peer 1 left the run") - t0 < 2.0
        assert elapsed < 5.0, elapsed
    else:
        assert rc == 130, err
        assert "interrupted" in err
    assert not (tmp_path / "o" / "final.npz").exists()


LOSE_ONE_MESSAGE = """
# Loaded at start-up by every process of the test's run (this file's folder is on PYTHONPATH): peer 0
# hands Zenoh nothing for its first {phase!r} message (of step {step}, if given) to peer 1, as if the
# link lost it.
from nodes import wire
from nodes.zenoh_transport import ZenohEndpoint

_put, _lost = ZenohEndpoint._put, []


def _lossy(self, dest, payload):
    _, (step, phase), _ = wire.decode(payload, self.run, dest, self.world)
    if self.rank == 0 and dest == 1 and phase == {phase!r} and {step!r} in (None, step) and not _lost:
        _lost.append(step)
        return
    _put(self, dest, payload)


ZenohEndpoint._put = _lossy
"""


@pytest.mark.parametrize("phase, step", [("fields", 30), ("bye", None)])
def test_a_lost_message_is_asked_for_again_and_the_run_is_unchanged(phase, step, tmp_path):
    # Given a 2-peer run whose peer 0 loses one message on the way to peer 1 (as a link might): a
    # halo message mid-run, or the goodbye after the final gather, when peer 0 waits for the others to leave
    (tmp_path / "inject").mkdir()
    (tmp_path / "inject" / "sitecustomize.py").write_text(LOSE_ONE_MESSAGE.format(phase=phase, step=step))
    env = dict(os.environ, PYTHONPATH=str(tmp_path / "inject"))
    p = sph("run", DAM, *SMALL, "--steps", "60", "--out", str(tmp_path / "two"), "--peers", "2", "--no-viewer",
            env=env)
    out, err = p.communicate(timeout=300)
    # Then peer 1, waiting for it, asks peer 0 to send it again, and the run ends as one process's does
    assert p.returncode == 0, err
    assert "peer 1, step " in err and f"waiting for its {phase!r} message, asked it to send that again" in err
    assert f"peer 0: peer 1 asked again for our {phase!r} message of step " in err
    assert "sending it again (1 of 3)" in err and f"peer 0's {phase!r} message came after" in err
    assert main(["run", DAM, *SMALL, "--steps", "60", "--out", str(tmp_path / "one"), "--quiet"]) == 0
    one, two = np.load(tmp_path / "one" / "final.npz"), np.load(tmp_path / "two" / "final.npz")
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(one[key], two[key]), key
    if phase == "bye":  # the summary was written before the goodbye
        return
    # and the summary counts what each peer did: nothing dropped, one message sent again
    peers = json.loads((tmp_path / "two" / "summary.json").read_text())["per_peer"]
    assert [p["dropped_messages"] for p in peers] == [0, 0]
    # (the lost message once; peer 1 may have asked for a merely slow one too on a loaded machine,
    # and every request is logged: nothing is sent again unasked)
    asks = sum("peer 1, step " in line and "asked it to send that again" in line for line in err.splitlines())
    assert list(peers[0]["resends"]["sent"]) == ["1"] and 1 <= peers[0]["resends"]["sent"]["1"] <= asks, err
    assert peers[1]["resends"]["asked"]["0"] >= 1
    assert peers[1]["resends"]["sent"] == {}


def test_peer_command_checks_its_arguments(capsys):
    assert main(["peer", DAM, "--rank", "2", "--world", "2", "--run-id", "x", "--listen", "tcp/127.0.0.1:1"]) == 2
    assert "--rank 2 --world 2" in capsys.readouterr().err
    assert main(["peer", DAM, "--rank", "0", "--world", "2", "--run-id", "a/b", "--listen", "tcp/127.0.0.1:1"]) == 2
    assert "--run-id" in capsys.readouterr().err
    assert main(["peer", DAM, "--rank", "0", "--world", "2", "--run-id", "x"]) == 2
    assert "--listen" in capsys.readouterr().err
