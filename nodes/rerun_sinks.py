"""Where a run's Rerun stream goes — all of them at once: a recording file, a native viewer, the
web viewer, an already running viewer's URL.

Rerun's SDK serves the web viewer on every interface (0.0.0.0) and on fixed ports; a second one on
the machine dies with "address in use". So the web viewer and the native viewer are separate
``rerun`` processes started here with ``--bind 127.0.0.1`` (loopback unless the user says
otherwise) on ports that are free — the defaults 9876 (gRPC) and 9090 (web) when they are, other
free ones when not; a port the user names that is busy is a clear error. The recording stream
then gets one sink per destination (``set_sinks``), so recording and watching live never exclude
each other.
"""
from __future__ import annotations

import atexit
import shutil
import socket
import subprocess
import time
from pathlib import Path

GRPC_PORT, WEB_PORT = 9876, 9090


class SinkError(ValueError):
    """A destination that cannot be opened (busy port, no rerun executable...)."""


def rerun_executable() -> str:
    """The rerun binary itself (rerun-sdk ships it in rerun_cli/): not the ``rerun`` script on the
    PATH, a Python wrapper whose child would survive a signal sent to it."""
    try:
        import rerun_cli
        exe = Path(rerun_cli.__file__).with_name("rerun")
    except ImportError:
        exe = None
    if exe is None or not exe.exists():
        found = shutil.which("rerun")
        if found is None:
            raise SinkError("the rerun executable is not installed next to this Python (pip install rerun-sdk)")
        return found
    return str(exe)


def port_free(port: int, host: str = "127.0.0.1") -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def choose_port(wanted: int | None, default: int, option: str, host: str = "127.0.0.1") -> int:
    """``wanted`` if given (it must be free), else ``default`` if free, else any free port."""
    if wanted is not None:
        if not port_free(wanted, host):
            raise SinkError(f"{option} {wanted}: that port is in use on {host} (another viewer?); choose another, "
                            "or leave the option out to take a free one")
        return wanted
    if port_free(default, host):
        return default
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def _die_with_parent():
    """In the child, before exec: get SIGTERM when the parent dies (Linux), however it dies."""
    import ctypes
    import signal
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass


def _wait_listening(proc, port: int, host: str, what: str, timeout: float = 30.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise SinkError(f"{what} exited at start (code {proc.returncode})")
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.settimeout(0.2)
            if s.connect_ex((host, port)) == 0:
                return
        time.sleep(0.1)
    proc.kill()
    raise SinkError(f"{what} did not listen on {host}:{port} within {timeout:g} s")


def serve_web(grpc_port: int | None = None, web_port: int | None = None, bind: str = "127.0.0.1",
              recording: Path | None = None):
    """Start ``rerun --serve-web`` on ``bind`` (a recording file to serve, or a proxy that live
    streams connect to); returns (process, gRPC URL for the SDK, web URL for a browser). The
    process is stopped when this Python exits, however it exits."""
    grpc = choose_port(grpc_port, GRPC_PORT, "--grpc-port", bind)
    web = choose_port(web_port, WEB_PORT, "--web-port", bind)
    cmd = [rerun_executable(), "--serve-web", "--bind", bind, "--port", str(grpc), "--web-viewer-port", str(web)]
    if recording is not None:
        cmd.insert(1, str(recording))
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
                            preexec_fn=_die_with_parent)
    atexit.register(_stop, proc)
    _wait_listening(proc, web, bind, "rerun --serve-web")
    url = f"rerun+http://{bind}:{grpc}/proxy"
    return proc, url, f"http://{bind}:{web}/?url={url}"


def spawn_native(grpc_port: int | None = None):
    """Open the native viewer (it stays open after the run) listening on loopback; returns its URL."""
    port = choose_port(grpc_port, GRPC_PORT, "--grpc-port")
    proc = subprocess.Popen([rerun_executable(), "--bind", "127.0.0.1", "--port", str(port), "--expect-data-soon"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    _wait_listening(proc, port, "127.0.0.1", "the native Rerun viewer")
    return f"rerun+http://127.0.0.1:{port}/proxy"


def _stop(proc):
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=3)
        except subprocess.TimeoutExpired:
            proc.kill()


def sinks_for(record: Path | None, spawn: bool, serve: bool, connect: str | None, grpc_port: int | None = None,
              web_port: int | None = None, announce=print) -> list:
    """The Rerun sinks of a run's viewer, every destination asked for, all at once."""
    import rerun as rr
    sinks = []
    if record is not None:
        Path(record).parent.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(str(record)))
    if serve:
        _, url, page = serve_web(grpc_port, web_port)
        announce(f"sph viewer: Rerun web viewer on {page}")
        sinks.append(rr.GrpcSink(url))
    if spawn:
        sinks.append(rr.GrpcSink(spawn_native(None if serve else grpc_port)))
    if connect:
        sinks.append(rr.GrpcSink(connect))
    return sinks
