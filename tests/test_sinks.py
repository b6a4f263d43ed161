"""Rerun destinations: a run records and streams at once; the web viewer listens on loopback only,
on free ports (a named busy port is a clear error); replay serves a recording the same way."""
import socket
import subprocess
import sys
import time
from pathlib import Path

from launch.local import free_ports
from nodes.rerun_sinks import choose_port, rerun_executable

ROOT = Path(__file__).resolve().parent.parent
TINY = ["configs/tiny.toml", "--steps", "30", "--set", "render.every=10", "--quiet"]


def listening_addresses(port: int) -> set[str]:
    """The local IPv4 addresses listening on ``port`` (from /proc/net/tcp)."""
    found = set()
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        local, state = line.split()[1], line.split()[3]
        address, p = local.split(":")
        if int(p, 16) == port and state == "0A":  # LISTEN
            found.add(socket.inet_ntoa(bytes.fromhex(address)[::-1]))
    return found


def image_count(rrd: Path) -> int:
    from nodes.recording import images
    return len(images(rrd))


def test_a_run_records_and_streams_to_a_running_viewer_at_once(tmp_path):
    # Given a headless Rerun receiver saving what it gets
    port = free_ports(1)[0]
    receiver = subprocess.Popen([rerun_executable(), "--save", str(tmp_path / "live.rrd"), "--port", str(port)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        time.sleep(2.0)
        # When a run records to its folder and streams to the receiver
        done = subprocess.run([sys.executable, "-m", "launch.cli", "run", *TINY, "--out", str(tmp_path / "out"),
                               "--connect", f"rerun+http://127.0.0.1:{port}/proxy"], cwd=ROOT, capture_output=True,
                              text=True, timeout=300)
        assert done.returncode == 0, done.stderr
        time.sleep(1.0)
    finally:
        receiver.terminate()
        receiver.wait(timeout=10)
    # Then both the recording and the live stream hold every frame
    assert image_count(tmp_path / "out" / "run.rrd") == 3
    assert image_count(tmp_path / "live.rrd") == 3


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
