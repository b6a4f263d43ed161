"""Where a run's Rerun stream goes — all of them at once: a recording file, a native viewer, the
web viewer, an already running viewer's URL.

Rerun's SDK serves the web viewer on every interface (0.0.0.0) and on fixed ports; a second one on
the machine dies with "address in use". So the web viewer and the native viewer are separate
``rerun`` processes started here with ``--bind 127.0.0.1`` (loopback unless the user says
otherwise) on ports that are free — the defaults 9876 (gRPC) and 9090 (web) when they are, other
free ones when not; a port the user names that is busy is a clear error. The recording stream
then gets one sink per destination (``set_sinks``), so recording and watching live never exclude
each other.

The file and the live destinations are two streams (``Streams``), because a Rerun stream is as
fast as its slowest sink: a live viewer that stops reading (a stopped process, a laptop lid shut
over an ssh tunnel) blocks the stream once its buffer is full (a few hundred MB), and with it the
recording file. So the file stream is logged by the viewer's writer thread and never waits for a
viewer; the live stream is fed by a thread of its own from a short queue of whole frames. When the
live side is behind, or frames come faster than ``--live-fps``, the newest frame replaces the one
waiting (counted as ``live.dropped_frames``); what must reach the viewer (the blueprint, static
entities, a frame that changes one) is never dropped.
"""
from __future__ import annotations

import atexit
import collections
import contextlib
import shutil
import socket
import subprocess
import threading
import time
from pathlib import Path

GRPC_PORT, WEB_PORT = 9876, 9090
LIVE_FPS = 10.0   # default --live-fps: frames per second sent to live viewers (a browser draws no more)
LIVE_FRAMES = 4   # frames waiting for the live stream with no frame-rate limit (--live-fps 0)


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


SPAWN_SETTLE_S = 2.0  # a native viewer that cannot draw here exits this soon after it starts listening


def spawn_native(grpc_port: int | None = None):
    """Open the native viewer (it stays open after the run) listening on loopback; returns its URL.
    A viewer that cannot open a window (no display, a graphics driver without what it needs:
    Mesa's llvmpipe lacks R32Float render targets) starts listening and exits within a moment:
    that is a SinkError quoting its own reason, before the run starts."""
    import tempfile
    port = choose_port(grpc_port, GRPC_PORT, "--grpc-port")
    errors = tempfile.TemporaryFile(mode="w+b")
    proc = subprocess.Popen([rerun_executable(), "--bind", "127.0.0.1", "--port", str(port), "--expect-data-soon"],
                            stdout=subprocess.DEVNULL, stderr=errors, start_new_session=True)
    try:
        _wait_listening(proc, port, "127.0.0.1", "the native Rerun viewer")
        proc.wait(timeout=SPAWN_SETTLE_S)
    except subprocess.TimeoutExpired:  # still running: it has its window
        errors.close()
        return f"rerun+http://127.0.0.1:{port}/proxy"
    except SinkError:
        pass
    errors.seek(0)
    text = errors.read()[-20000:].decode(errors="replace")
    errors.close()
    lines = [ln.strip() for ln in text.splitlines() if ln.strip().startswith("Error:")]
    reason = lines[-1][len("Error:"):].strip() if lines else f"exit code {proc.returncode}"
    raise SinkError(f"--spawn: the native Rerun viewer could not start here ({reason[:300]}); use --serve-web and "
                    "a browser, or leave --spawn out and open the recording later (sph replay OUT/run.rrd)")


def _stop(proc):
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=3)
        except subprocess.TimeoutExpired:
            proc.kill()


def sinks_for(record: Path | None, spawn: bool, serve: bool, connect: str | None, grpc_port: int | None = None,
              web_port: int | None = None, announce=print) -> tuple:
    """(the file sink or None, [the live sinks]) of a run's viewer: every destination asked for."""
    import rerun as rr
    file_sink, live = None, []
    if record is not None:
        Path(record).parent.mkdir(parents=True, exist_ok=True)
        file_sink = rr.FileSink(str(record))
    if serve:
        _, url, page = serve_web(grpc_port, web_port)
        announce(f"sph viewer: Rerun web viewer on {page}")
        live.append(rr.GrpcSink(url))
    if spawn:
        live.append(rr.GrpcSink(spawn_native(None if serve else grpc_port)))
    if connect:
        live.append(rr.GrpcSink(connect))
    return file_sink, live


class Streams:
    """A viewer's Rerun output: ``file`` (a RecordingStream, or anything with its ``log``,
    ``set_time``, ``send_blueprint``, ``flush`` and ``disconnect``; called in the caller's thread)
    and ``live`` (a RecordingStream to the live sinks, called only by the live thread). Either may be
    None. The calls between ``frame()``'s enter and exit are one frame for the live side; calls
    outside a frame, static entities and blueprints are never dropped from it. ``live_fps`` > 0: at
    most that many frames per second go live (the newest waiting one); 0: no limit."""

    def __init__(self, file, live=None, live_fps: float = LIVE_FPS):
        self.file, self.live, self.live_fps = file, live, float(live_fps)
        self.live_frames = 0       # frames sent to the live stream
        self.live_dropped = 0      # frames not sent live: replaced by a newer one while waiting
        self.live_latency_ms = []  # per frame sent live: its publication -> handed to the live stream
        self._batch = None         # [(method, args, kwargs)] of the frame being logged; None outside one
        self._keep = False         # the frame being logged must reach the live viewer
        self._waiting = collections.deque()  # [keep, calls, published] in order
        self._busy = False
        self._closing = False
        self._cond = threading.Condition()
        self._thread = None
        if live is not None:
            self._thread = threading.Thread(target=self._live_loop, name="sph-viewer-live", daemon=True)
            self._thread.start()

    # -- what the viewer calls ---------------------------------------------------------------
    def log(self, entity, *args, static: bool = False, **kwargs):
        self._call("log", (entity,) + args, dict(kwargs, static=static), keep=static)

    def set_time(self, *args, **kwargs):
        self._call("set_time", args, kwargs, keep=False)

    def send_blueprint(self, *args, **kwargs):
        self._call("send_blueprint", args, kwargs, keep=True)

    @contextlib.contextmanager
    def frame(self, published: float | None = None):
        """Log one frame (``published``: the time.time() its newest framelet was published)."""
        self._batch, self._keep = [], False
        try:
            yield self
        finally:
            calls, keep = self._batch, self._keep
            self._batch = None
            if self.live is not None:
                self._hand_over(keep, calls, published)

    def close(self, timeout: float = 30.0) -> bool:
        """Finish the file (flushed, its footer written), then give the live stream up to ``timeout``
        seconds to take what waits; False if it did not (a live viewer that stopped reading: the live
        stream is then held, never dropped, since dropping it would wait for ever)."""
        if self.file is not None:
            self.file.flush(timeout_sec=timeout)
            self.file.disconnect()
        if self.live is None:
            return True
        deadline = time.monotonic() + timeout
        with self._cond:
            self._closing = True
            self._cond.notify_all()
            while (self._waiting or self._busy) and time.monotonic() < deadline:
                self._cond.wait(max(0.01, deadline - time.monotonic()))
            taken = not (self._waiting or self._busy)
        if taken:
            try:
                self.live.flush(timeout_sec=max(0.1, deadline - time.monotonic()))
            except RuntimeError:
                taken = False
        if not taken:
            return False
        self.live.disconnect()
        return True

    def summary(self) -> dict | None:
        """summary.json's viewer "live" section (None without a live destination)."""
        if self.live is None:
            return None
        out = {"frames": self.live_frames, "dropped_frames": self.live_dropped, "fps_limit": self.live_fps or None}
        if self.live_latency_ms:
            out["latency_ms"] = {"median": float(sorted(self.live_latency_ms)[len(self.live_latency_ms) // 2]),
                                 "max": float(max(self.live_latency_ms))}
        return out

    # -- inside ----------------------------------------------------------------------------------
    def _call(self, method: str, args: tuple, kwargs: dict, keep: bool):
        if self.file is not None:
            getattr(self.file, method)(*args, **kwargs)
        if self.live is None:
            return
        if self._batch is not None:
            self._batch.append((method, args, kwargs))
            self._keep |= keep
        else:
            self._hand_over(True, [(method, args, kwargs)], None)

    def _hand_over(self, keep: bool, calls: list, published):
        with self._cond:
            if not keep:
                room = 1 if self.live_fps > 0 else LIVE_FRAMES  # limited: only the newest waits for its turn
                droppable = [item for item in self._waiting if not item[0]]
                while len(droppable) >= room:
                    self._waiting.remove(droppable.pop(0))
                    self.live_dropped += 1
            self._waiting.append([keep, calls, published])
            self._cond.notify_all()

    def _live_loop(self):
        next_slot = 0.0
        while True:
            with self._cond:
                while True:
                    if not self._waiting:
                        if self._closing:
                            return
                        self._cond.wait()
                        continue
                    keep, calls, published = self._waiting[0]
                    wait = next_slot - time.monotonic()
                    if published is None or self.live_fps <= 0 or wait <= 0 or self._closing:
                        break
                    self._cond.wait(wait)  # the frame-rate limit: a newer frame may replace this one meanwhile
                self._waiting.popleft()
                self._busy = True
            try:
                for method, args, kwargs in calls:  # blocks while a live viewer is not reading
                    getattr(self.live, method)(*args, **kwargs)
            finally:
                with self._cond:
                    self._busy = False
                    if published is not None:
                        self.live_frames += 1
                        self.live_latency_ms.append(1e3 * (time.time() - published))
                        if self.live_fps > 0:
                            next_slot = time.monotonic() + 1.0 / self.live_fps
                    self._cond.notify_all()
