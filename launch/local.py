"""``sph run --peers N``: N peer processes on this machine, talking Zenoh over loopback.

Each peer is a fresh interpreter (``python -m launch.cli peer ...``: spawned, never forked after
Zenoh is open) listening on its own ``tcp/127.0.0.1:PORT`` and connecting to every other peer's
(a full mesh; multicast scouting off). Numba threads per peer default to cores / N. Rank 0 gathers
the result and writes the usual outputs. The launcher watches the processes: if one exits with an
error the others notice through Zenoh liveliness, and any still running after a grace period are
stopped; Ctrl-C stops them all.
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


def peer_command(config: Path, rank: int, world: int, run_id: str, listen: str, connect: list[str], out: Path,
                 args) -> list[str]:
    source = ["--resume", str(args.resume)] if getattr(args, "resume", None) else [str(config)]
    cmd = [sys.executable, "-m", "launch.cli", "peer", *source, "--rank", str(rank), "--world", str(world),
           "--run-id", run_id, "--listen", listen, "--out", str(out), "--timeout", str(args.timeout)]
    if getattr(args, "checkpoint_every", None) is not None:
        cmd += ["--checkpoint-every", str(args.checkpoint_every)]
    for ep in connect:
        cmd += ["--connect", ep]
    return cmd + run_options(args) + (["--quiet"] if args.quiet else [])


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
    cmd = [sys.executable, "-m", "launch.cli", "viewer", str(config), "--run-id", run_id, "--listen", listen,
           "--world", str(n_peers)]  # (a resumed run's viewer gets the checkpoint's scene.toml)
    if viewer["record"]:
        cmd += ["--record", str(viewer["record"]), "--stats", str(Path(viewer["record"]).with_name("viewer.json"))]
    if viewer["spawn"]:
        cmd.append("--spawn")
    if viewer["serve_web"]:
        cmd.append("--serve-web")
    if viewer["connect"]:
        cmd += ["--rerun-url", viewer["connect"]]
    for o in args.overrides:
        cmd += ["--set", o]
    return cmd


def _start_viewer(cmd, env, timeout: float = 120.0):
    """Start the viewer and wait for its "viewer ready" line (subscribed), so no frame is missed."""
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, text=True)
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
            raise RuntimeError(f"the viewer did not start (exit code {proc.returncode})")
    return proc


def run_local_peers(config: Path, n_peers: int, out: Path, args, viewer: dict | None = None) -> int:
    """Start the viewer (if any) and the peers, wait for them; return the exit code (0, or the first
    failing peer's)."""
    threads = args.threads or default_threads(n_peers)
    run_id = new_run_id()
    ports = free_ports(n_peers + 1)
    endpoints = [f"tcp/127.0.0.1:{p}" for p in ports[:n_peers]]
    viewer_endpoint = f"tcp/127.0.0.1:{ports[-1]}"
    env = dict(os.environ, NUMBA_NUM_THREADS=str(threads), PYTHONUNBUFFERED="1", RERUN_ANALYTICS="0")
    log.info("run %s: %d peers on this machine, %d numba threads each, endpoints %s", run_id, n_peers, threads,
             ", ".join(endpoints))
    procs, view = [], None
    try:
        if viewer is not None:
            view = _start_viewer(viewer_command(config, run_id, viewer_endpoint, n_peers, viewer, args), env)
        for rank in range(n_peers):
            # each peer connects to the lower ranks and is connected to by the higher ones (a full
            # mesh), and to the viewer
            connect = endpoints[:rank] + ([viewer_endpoint] if view is not None else [])
            cmd = peer_command(config, rank, n_peers, run_id, endpoints[rank], connect, out, args)
            if view is None:
                cmd.append("--no-frames")
            procs.append(subprocess.Popen(cmd, env=env))
        code = _watch(procs)
        if view is not None and code == 0:
            try:
                view.wait(timeout=30)  # it stops by itself after rank 0's end notice
            except subprocess.TimeoutExpired:
                log.warning("the viewer did not stop 30 s after the peers; stopping it")
        # after a failure the viewer is stopped at once (SIGTERM: it flushes the recording first)
        return code
    except KeyboardInterrupt:
        _stop(procs + ([view] if view else []), signal.SIGINT)
        raise
    finally:
        _stop(procs + ([view] if view else []), signal.SIGTERM)


def _watch(procs, grace: float = 5.0) -> int:
    """Wait for every peer. After the first failure, give the others ``grace`` seconds to notice
    (they exit on their own through Zenoh liveliness) before stopping them."""
    failed_at, first_failure = None, None
    while True:
        codes = [p.poll() for p in procs]
        for rank, code in enumerate(codes):
            if code not in (None, 0) and first_failure is None:
                first_failure = (rank, code)
                failed_at = time.monotonic()
                how = f"was killed by signal {-code}" if code < 0 else f"exited with code {code}"
                log.error("peer %d %s; stopping the run", rank, how)
        if all(c is not None for c in codes):
            break
        if failed_at is not None and time.monotonic() - failed_at > grace:
            stuck = [r for r, c in enumerate(codes) if c is None]
            log.error("peers %s still running %.0f s after peer %d failed; stopping them", stuck, grace,
                      first_failure[0])
            _stop(procs, signal.SIGTERM)
            break
        time.sleep(0.05)
    if first_failure is None:
        return 0
    code = first_failure[1]
    return code if code > 0 else 4  # killed by a signal: "a peer was lost" (cli.EXIT_PEER)


def _stop(procs, sig):
    for p in procs:
        if p.poll() is None:
            p.send_signal(sig)
    deadline = time.monotonic() + 3.0
    for p in procs:
        try:
            p.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
