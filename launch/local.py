"""``sph run --peers N``: N peer processes on this machine, talking Zenoh over loopback.

Each peer is a fresh interpreter (``python -m launch.cli peer ...``: spawned, never forked after
Zenoh is open) listening on its own ``tcp/127.0.0.1:PORT`` and connecting to every other peer's
(a full mesh; multicast scouting off). Numba threads per peer default to cores / N. Rank 0 gathers
the result and writes the usual outputs. The launcher watches the processes (launch/supervise.py):
if one exits with an error the others notice through Zenoh liveliness, a stopped one is killed at
once and any still running after a grace period are stopped; with --restarts a lost peer restarts
the run from the newest checkpoint; Ctrl-C stops them all. Every peer (and the viewer) gets a pipe
as stdin and --watch-stdin, so a killed launcher takes them down within a second.
"""
from __future__ import annotations

import logging
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

from launch import supervise
from sphcore import checkpoint
from sphcore.children import module_command, module_env

log = logging.getLogger("sph.launch")


def free_ports(n: int) -> list[int]:
    """n distinct loopback ports that were free a moment ago."""
    socks, ports = [], []
    try:
        for _ in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.bind(("127.0.0.1", 0))
            socks.append(s)
            ports.append(s.getsockname()[1])
    finally:
        for s in socks:
            s.close()
    return ports


def new_run_id() -> str:
    return uuid.uuid4().hex[:12]


def default_threads(n_peers: int) -> int:
    return max(1, (os.cpu_count() or 1) // n_peers)


def prepare_security(args, out: Path, peer_hosts: list[list[str]], viewer_hosts=()) -> str:
    """Make the run's credentials (a fresh CA and one certificate per process) in OUT/tls, readable
    only by this user, and set ``args.tls_dir``; returns the endpoint scheme ("tls", or "tcp" with
    --insecure). The previous run's OUT/tls is replaced: its CA is useless without its key anyway."""
    import shutil

    from nodes import security
    if getattr(args, "insecure", False):
        log.warning("--insecure: plain TCP between the run's processes, no authentication, no encryption: "
                    "any process that reaches these ports can join, read or steer the run")
        args.tls_dir = None
        return "tcp"
    folder = Path(out) / "tls"
    if folder.exists():
        shutil.rmtree(folder)
    security.make_run_credentials(folder, peer_hosts, viewer_hosts or security.LOOPBACK_NAMES)
    args.tls_dir = folder
    return "tls"


def security_options(args) -> list[str]:
    """The security flags of a process the launcher starts on this machine."""
    folder = getattr(args, "tls_dir", None)
    return ["--tls", str(folder)] if folder is not None else ["--insecure"]


def peer_command(config: Path, rank: int, world: int, run_id: str, listen: str, connect: list[str], out: Path,
                 args) -> list[str]:
    source = ["--resume", str(args.resume)] if getattr(args, "resume", None) else [str(config)]
    cmd = module_command("launch.cli", "peer", *source, "--rank", str(rank), "--world", str(world),
                         "--run-id", run_id, "--listen", listen, "--out", str(out), "--timeout", str(args.timeout))
    if getattr(args, "checkpoint_every", None) is not None:
        cmd += ["--checkpoint-every", str(args.checkpoint_every)]
    for ep in connect:
        cmd += ["--zenoh", ep]
    return cmd + run_options(args) + security_options(args) + (["--quiet"] if args.quiet else [])


def run_options(args) -> list[str]:
    """The `sph run` options every peer of the run must get identically."""
    cmd = []
    if getattr(args, "backend", "cpu") != "cpu":
        cmd += ["--backend", args.backend]
    if args.precision:
        cmd += ["--precision", args.precision]
    if args.steps is not None:
        cmd += ["--steps", str(args.steps)]
    if args.until is not None:
        cmd += ["--until", repr(args.until)]
    for o in args.overrides:
        cmd += ["--set", o]
    return cmd


def viewer_command(config: Path, run_id: str, listen: str, n_peers: int, viewer: dict, args) -> list[str]:
    # (a resumed run gets the checkpoint's scene.toml)
    cmd = module_command("launch.cli", "viewer", str(config), "--run-id", run_id, "--listen", listen,
                         "--world", str(n_peers)) + security_options(args)
    if viewer["record"]:
        cmd += ["--record", str(viewer["record"]), "--stats", str(Path(viewer["record"]).with_name("viewer.json"))]
    if viewer["spawn"]:
        cmd.append("--spawn")
    if viewer["serve_web"]:
        cmd.append("--serve-web")
    for option in ("grpc_port", "web_port"):
        if viewer.get(option) is not None:
            cmd += ["--" + option.replace("_", "-"), str(viewer[option])]
    if viewer["connect"]:
        cmd += ["--rerun-url", viewer["connect"]]
    if viewer.get("live_fps") is not None:
        cmd += ["--live-fps", repr(float(viewer["live_fps"]))]
    for o in args.overrides:
        cmd += ["--set", o]
    return cmd


def _start_viewer(cmd, env, timeout: float = 120.0):
    """Start the viewer and wait for its "viewer ready" line (subscribed), so no frame is missed."""
    # stdin: a pipe we keep open (--watch-stdin: the viewer stops when we are gone)
    proc = subprocess.Popen(cmd, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    ready = threading.Event()

    def read():
        for line in proc.stdout:
            if line.strip() == "viewer ready":
                ready.set()
            else:
                sys.stdout.write(line)

    threading.Thread(target=read, daemon=True).start()
    deadline = time.monotonic() + timeout
    while not ready.wait(0.1):
        if proc.poll() is not None or time.monotonic() > deadline:
            _stop([proc], signal.SIGTERM)
            from nodes.rerun_sinks import SinkError
            raise SinkError(f"the viewer process did not start (exit code {proc.returncode}; its reason is above); "
                            "no peer was started")
    return proc


def write_run_info(out: Path, run_id: str, world: int, endpoints: list[str], args):
    """OUT/run.json: what ``sph control OUT CMD`` (and a viewer by hand) needs to reach the running
    run: its id, the peers' endpoints (rank 0's first), the peer count and the credentials folder
    (None: --insecure). Rewritten, atomically, when a restart moves the peers to new ports."""
    import json
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    tls = getattr(args, "tls_dir", None)
    info = {"run_id": run_id, "world": world, "endpoints": list(endpoints),
            "tls": str(Path(tls).resolve()) if tls is not None else None, "launcher_pid": os.getpid()}
    tmp = out / ".run.json.tmp"
    tmp.write_text(json.dumps(info, indent=1) + "\n")
    os.replace(tmp, out / "run.json")


def run_local_peers(config: Path, n_peers: int, out: Path, args, viewer: dict | None = None) -> int:
    """Start the viewer (if any) and the peers, wait for them; return the exit code (0, or the first
    failing peer's). With ``args.restarts`` K, a lost peer restarts the run — every peer, on new
    ports, the same run id (the viewer keeps watching) — from the newest checkpoint in
    OUT/checkpoints, up to K times (launch/supervise.py)."""
    threads = args.threads or default_threads(n_peers)
    run_id = new_run_id()
    scheme = prepare_security(args, out, [["127.0.0.1"]] * n_peers)
    ports = free_ports(n_peers + 1)
    endpoints = [f"{scheme}/127.0.0.1:{p}" for p in ports[:n_peers]]
    viewer_endpoint = f"{scheme}/127.0.0.1:{ports[-1]}"
    # this code in every child, whatever folder the run was started in (sphcore/children.py)
    env = module_env(dict(os.environ, NUMBA_NUM_THREADS=str(threads), PYTHONUNBUFFERED="1", RERUN_ANALYTICS="0"))
    log.info("run %s: %d peers on this machine, %d numba threads each, endpoints %s", run_id, n_peers, threads,
             ", ".join(endpoints))
    view = None
    restarts = getattr(args, "restarts", 0) or 0

    def start(attempt, resume, history):
        eps = endpoints if not history else [f"{scheme}/127.0.0.1:{p}" for p in free_ports(n_peers)]
        run_args = supervise.resumed_args(args, resume)
        write_run_info(out, run_id, n_peers, eps, args)
        for rank in range(n_peers):
            # each peer connects to the lower ranks and is connected to by the higher ones (a full
            # mesh), and to the viewer
            connect = eps[:rank] + ([viewer_endpoint] if view is not None else [])
            cmd = peer_command(config, rank, n_peers, run_id, eps[rank], connect, out, run_args)
            if view is None:
                cmd.append("--no-frames")
            cmd += supervise.peer_options(restarts, history)
            attempt.add(subprocess.Popen(cmd, env=env, **supervise.popen_options()))

    origin = checkpoint.latest(args.resume) if getattr(args, "resume", None) else None
    supervisor = supervise.Supervisor(start, restarts, out / "checkpoints", origin_step=origin[1] if origin else 0)
    try:
        if viewer is not None:
            view = _start_viewer(viewer_command(config, run_id, viewer_endpoint, n_peers, viewer, args)
                                 + ["--watch-stdin"], env)
        code = supervisor.run()
        if view is not None and code == 0:
            try:
                view.wait(timeout=30)  # it stops by itself after rank 0's end notice
                _add_viewer_summary(out / "summary.json", viewer)
            except subprocess.TimeoutExpired:
                log.warning("the viewer did not stop 30 s after the peers; stopping it")
        # after a failure the viewer is stopped at once (SIGTERM: it flushes the recording first)
        return code
    except KeyboardInterrupt:
        _stop(supervisor.processes() + ([view] if view else []), signal.SIGINT)
        raise
    finally:
        _stop(supervisor.processes() + ([view] if view else []), signal.SIGTERM)


def _add_viewer_summary(summary_path: Path, viewer: dict):
    """summary.json's "viewer" (frames, drops, latency, recording size) from the viewer's viewer.json."""
    import json

    from sphcore.output import write_summary
    stats = Path(viewer["record"]).with_name("viewer.json") if viewer.get("record") else None
    if stats is None or not stats.is_file() or not summary_path.is_file():
        return
    summary = json.loads(summary_path.read_text())
    summary["viewer"] = json.loads(stats.read_text())
    write_summary(summary_path, summary)


def _watch(procs, grace: float = supervise.GRACE_S) -> int:
    """Wait for every peer (launch/supervise.py ``watch``); returns the run's exit code."""
    return supervise.watch(procs, grace).code


def _stop(procs, sig):
    """Stop the processes still running with ``sig`` (stopped ones too), SIGKILL after 2 s."""
    supervise.stop(procs, sig)
