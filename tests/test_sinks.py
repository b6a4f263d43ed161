"""Rerun destinations: a run records and streams at once; the web viewer listens on loopback only,
on free ports (a named busy port is a clear error); replay serves a recording the same way."""
import contextlib
import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from launch.local import free_ports
from nodes.rerun_sinks import choose_port, rerun_executable

ROOT = Path(__file__).resolve().parent.parent
TINY = ["configs/tiny.toml", "--steps", "30", "--set", "render.every=10", "--quiet"]
LIVE_ALL = ["--live-fps", "0"]  # every frame live while the receiver keeps up (the default sends 10 per second)


def listening_addresses(port: int) -> set[str]:
    """The local IPv4 addresses listening on ``port`` (from /proc/net/tcp)."""
    found = set()
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        local, state = line.split()[1], line.split()[3]
        address, p = local.split(":")
        if int(p, 16) == port and state == "0A":  # LISTEN
            found.add(socket.inet_ntoa(bytes.fromhex(address)[::-1]))
    return found


def frames(rrd: Path) -> dict:
    from nodes.recording import images
    return images(rrd)


@contextlib.contextmanager
def receiver(rrd: Path):
    """A headless Rerun receiver saving what it gets to ``rrd``: yields (process, its gRPC URL);
    killed at the end (a stopped one too)."""
    port = free_ports(1)[0]
    proc = subprocess.Popen([rerun_executable(), "--save", str(rrd), "--port", str(port)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        time.sleep(2.0)
        yield proc, f"rerun+http://127.0.0.1:{port}/proxy"
    finally:
        proc.terminate()
        proc.send_signal(signal.SIGCONT)  # a stopped receiver handles the SIGTERM once it runs again
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)


# the headless `rerun --save` receiver writes its file without a footer when a signal stops it (SIGTERM
# and SIGINT alike, rerun 0.41): reading it back falls back to a scan, with a warning; the run's own
# recording (run.rrd) has its footer, and its reading stays under the default warning filters
@pytest.mark.filterwarnings("ignore:RRD file has no footer/manifest.*live.rrd")
def test_a_run_records_and_streams_to_a_running_viewer_at_once(tmp_path):
    # Given a headless Rerun receiver saving what it gets
    with receiver(tmp_path / "live.rrd") as (_, url):
        # When a run records to its folder and streams to the receiver
        done = subprocess.run([sys.executable, "-m", "launch.cli", "run", *TINY, "--out", str(tmp_path / "out"),
                               "--connect", url, *LIVE_ALL], cwd=ROOT, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr
        time.sleep(1.0)
    # Then the recording and the live stream hold the same frames, every one, and the blueprint
    from nodes.recording import blueprint, entity_steps
    recorded, live = frames(tmp_path / "out" / "run.rrd"), frames(tmp_path / "live.rrd")
    assert sorted(recorded) == sorted(live) == [10, 20, 30]
    for step in recorded:
        assert np.array_equal(recorded[step], live[step]), step
    for rrd in (tmp_path / "out" / "run.rrd", tmp_path / "live.rrd"):
        assert any(v["origin"] == "/composite" for v in blueprint(rrd)["views"]), rrd
        assert entity_steps(rrd)["/fluid/points"] == [10, 20, 30]  # the point cloud is on by default
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())["viewer"]
    assert summary["frames"] == 3 and summary["dropped_frames"] == 0
    assert summary["live"]["frames"] == 3 and summary["live"]["dropped_frames"] == 0 and not summary["stalled"]
    assert summary["record_mb"] == pytest.approx((tmp_path / "out" / "run.rrd").stat().st_size / 1e6, rel=0.2)
    assert "MB per frame recorded" in done.stdout


def test_serving_the_web_viewer_keeps_the_recording(tmp_path):
    grpc, web = free_ports(2)
    done = subprocess.run([sys.executable, "-m", "launch.cli", "run", *TINY, "--out", str(tmp_path / "out"),
                           "--serve-web", "--web-port", str(web), "--grpc-port", str(grpc)], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert f"http://127.0.0.1:{web}/" in done.stdout
    assert sorted(frames(tmp_path / "out" / "run.rrd")) == [10, 20, 30]


def test_replay_serves_on_loopback_and_a_busy_port_is_a_clear_error(tmp_path):
    rrd = tmp_path / "r.rrd"
    done = subprocess.run([sys.executable, "-m", "launch.cli", "run", *TINY, "--out", str(tmp_path / "out"),
                           "--record", str(rrd)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    grpc, web = free_ports(2)
    p = subprocess.Popen([sys.executable, "-m", "launch.cli", "replay", str(rrd), "--serve-web", "--web-port",
                          str(web), "--grpc-port", str(grpc)], cwd=ROOT, stderr=subprocess.PIPE, text=True)
    try:
        line = p.stderr.readline()
        assert f"http://127.0.0.1:{web}/" in line, line
        # Then both ports listen on 127.0.0.1 and nowhere else
        assert listening_addresses(web) == {"127.0.0.1"} and listening_addresses(grpc) == {"127.0.0.1"}
        # A second replay on the same web port is refused with the reason; without ports it takes free ones
        again = subprocess.run([sys.executable, "-m", "launch.cli", "replay", str(rrd), "--serve-web", "--web-port",
                                str(web)], cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert again.returncode == 2 and f"--web-port {web}: that port is in use" in again.stderr, again.stderr
        assert "Traceback" not in again.stderr
    finally:
        p.terminate()
        p.wait(timeout=10)
    # And the server went with it
    deadline = time.monotonic() + 5
    while listening_addresses(web) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert listening_addresses(web) == set()


def test_a_taken_default_port_gives_a_free_one():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        taken = s.getsockname()[1]
        got = choose_port(None, taken, "--web-port")
        assert got != taken and got > 0


class Recorder:
    """A stand-in for a Rerun stream: keeps the entity paths it was given; ``gate`` (an Event) held
    closed blocks every call, as a stream to a viewer that stopped reading does once its buffer is full."""

    def __init__(self, gate=None):
        self.logged, self.gate = [], gate

    def log(self, entity, *args, static=False):
        if self.gate is not None:
            self.gate.wait()
        self.logged.append(entity)

    def set_time(self, *args, **kwargs):
        pass

    def send_blueprint(self, *args, **kwargs):
        self.log("blueprint")

    def flush(self, timeout_sec=None):
        if self.gate is not None and not self.gate.wait(timeout_sec):
            raise RuntimeError("flush timed out")

    def disconnect(self):
        pass


def test_a_live_viewer_that_stops_reading_never_holds_up_the_recording_file():
    import threading

    from nodes.rerun_sinks import Streams
    # Given a file stream and a live stream whose viewer stopped reading
    file, gate = Recorder(), threading.Event()
    live = Recorder(gate)
    streams = Streams(file, live, live_fps=0)
    streams.send_blueprint("layout")
    # When 50 frames are logged
    start = time.perf_counter()
    for step in range(50):
        with streams.frame(published=time.time()):
            streams.log(f"frame/{step}")
    logging_took = time.perf_counter() - start
    # Then the file got every frame at once, and closing gives up on the live side after its timeout
    assert file.logged == ["blueprint"] + [f"frame/{i}" for i in range(50)]
    assert logging_took < 1.0, logging_took
    start = time.perf_counter()
    assert streams.close(timeout=0.5) is False
    assert time.perf_counter() - start < 2.0
    # and the live side kept only the newest few frames waiting, the rest dropped and counted
    assert streams.live_dropped >= 50 - 4 - 1 and streams.summary()["dropped_frames"] == streams.live_dropped
    gate.set()  # the viewer reads again: what waited goes out, the newest frame last
    deadline = time.monotonic() + 5
    while "frame/49" not in live.logged and time.monotonic() < deadline:
        time.sleep(0.01)
    assert live.logged[0] == "blueprint" and live.logged[-1] == "frame/49"


def test_live_frames_are_limited_to_the_frame_rate_and_the_newest_is_sent():
    from nodes.rerun_sinks import Streams
    # Given a live viewer that keeps up and a limit of 20 frames per second
    file, live = Recorder(), Recorder()
    streams = Streams(file, live, live_fps=20)
    # When 60 frames come 100 per second, with a static entity logged in frame 30
    for step in range(60):
        with streams.frame(published=time.time()):
            streams.log(f"frame/{step}")
            if step == 30:
                streams.log("info", static=True)
        time.sleep(0.01)
    assert streams.close(timeout=5.0) is True
    # Then the file has all of them; live got about 20 per second, the last frame and the static one
    assert len(file.logged) == 61
    sent = [e for e in live.logged if e.startswith("frame/")]
    assert 6 <= len(sent) <= 20, sent
    assert sent[-1] == "frame/59" and "info" in live.logged and "frame/30" in live.logged
    assert sent == sorted(sent, key=lambda e: int(e.split("/")[1]))
    assert streams.live_frames + streams.live_dropped == 60


FAKE_VIEWER = """#!{python}
import socket, sys, time
port = int(sys.argv[sys.argv.index("--port") + 1])
s = socket.socket()
s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
s.bind(("127.0.0.1", port))
s.listen()
if {dies}:
    time.sleep(0.3)
    print("WARN something harmless", file=sys.stderr)
    print("Error: app creation error: no adapter can draw R32Float", file=sys.stderr)
    sys.exit(1)
time.sleep(8)  # (long enough for the test; a real viewer stays open)
"""


@pytest.mark.parametrize("dies", [True, False])
def test_spawn_opens_the_native_viewer_or_says_why_it_cannot(tmp_path, monkeypatch, dies):
    import os

    from nodes import rerun_sinks
    # Given a native viewer that starts listening and then either keeps its window or exits at once
    # (as Rerun's does on Mesa's llvmpipe: no R32Float render target)
    exe = tmp_path / "rerun"
    exe.write_text(FAKE_VIEWER.format(python=sys.executable, dies=dies))
    os.chmod(exe, 0o755)
    monkeypatch.setattr(rerun_sinks, "rerun_executable", lambda: str(exe))
    port = free_ports(1)[0]
    # When --spawn opens it
    if dies:
        # Then a viewer that exited is a clear error quoting its reason, before anything runs
        with pytest.raises(rerun_sinks.SinkError, match="could not start here .app creation error: no adapter"):
            rerun_sinks.spawn_native(port)
    else:
        # Then one that stays gets the stream
        assert rerun_sinks.spawn_native(port) == f"rerun+http://127.0.0.1:{port}/proxy"
        assert listening_addresses(port) == {"127.0.0.1"}


@pytest.mark.slow
def test_a_run_streaming_to_a_stopped_viewer_records_every_frame(tmp_path):
    import os
    # Given a live receiver that stops reading (SIGSTOP) before the run starts
    with receiver(tmp_path / "live.rrd") as (proc, url):
        os.kill(proc.pid, signal.SIGSTOP)
        done = subprocess.run([sys.executable, "-m", "launch.cli", "run", "configs/dam_break.toml", "--set",
                               "particles.spacing=0.04", "--steps", "300", "--set", "render.every=10", "--quiet",
                               "--out", str(tmp_path / "out"), "--connect", url],
                              cwd=ROOT, capture_output=True, text=True, timeout=300)
    # Then the run ends, its recording holds every frame, and summary.json says the live side stalled
    assert done.returncode == 0, done.stderr
    assert sorted(frames(tmp_path / "out" / "run.rrd")) == list(range(10, 301, 10))
    shown = json.loads((tmp_path / "out" / "summary.json").read_text())["viewer"]
    assert shown["frames"] == 30 and shown["stalled"] is True
    assert "the live Rerun viewer stopped reading" in done.stderr
