"""``sph run CONFIG --hosts FILE``: one peer per line of a hosts file, started over ssh.

Hosts file (``#`` starts a comment; rank = line order among the non-empty lines)::

    # host            port   [threads]
    node01.cluster    7447   16
    node02.cluster    7447   16
    10.0.0.7          7450

Peer R runs ``cd REMOTE_DIR && PYTHON -m launch.cli peer CONFIG --rank R ...`` on its host,
listening on ``tls/LISTEN_HOST:PORT`` (``--listen-host``, default: its own HOST) and connecting to
every lower rank's ``tls/HOST:PORT`` (a full mesh; no router, no multicast). The launcher makes the
run's credentials in OUT/tls on this machine (nodes/security.py: one certificate per peer, naming
its HOST, so that TLS verifies every peer dialled) and hands each peer its own over ssh's stdin:
no key is written on a remote host and none appears on a command line. ``--insecure`` runs plain
TCP instead, and only where every host is a loopback address. The repository (and its environment) must be at REMOTE_DIR on
every host — a shared file system, or the same checkout everywhere. Rank 0 writes the outputs on
its host. The watch and restart loop is the local launcher's (launch/supervise.py): a failed peer
stops the run (or, with --restarts, restarts it from the newest checkpoint), Ctrl-C stops all; each
peer runs with --watch-stdin, so it stops when its ssh connection (and so its stdin) closes.
"""
from __future__ import annotations

import logging
import shlex
import signal
import subprocess
from dataclasses import dataclass
from pathlib import Path

from launch import supervise
from launch.local import _stop, new_run_id, prepare_security, run_options, write_run_info

log = logging.getLogger("sph.launch")


@dataclass(frozen=True)
class Host:
    name: str
    port: int
    threads: int | None = None


def read_hosts(path: Path) -> list[Host]:
    """Parse a hosts file; ValueError names the line and what is wrong."""
    try:
        text = Path(path).read_text()
    except OSError as e:
        raise ValueError(f"cannot read hosts file {str(path)!r}: {e.strerror}") from None
    hosts = []
    for number, line in enumerate(text.splitlines(), 1):
        fields = line.split("#", 1)[0].split()
        if not fields:
            continue
        where = f"{path}:{number}"
        if len(fields) not in (2, 3):
            raise ValueError(f"{where}: expected 'HOST PORT [THREADS]', got {line.strip()!r}")
        try:
            port = int(fields[1])
            threads = int(fields[2]) if len(fields) == 3 else None
        except ValueError:
            raise ValueError(f"{where}: PORT and THREADS must be integers, got {line.strip()!r}") from None
        if not 1 <= port <= 65535 or (threads is not None and threads < 1):
            raise ValueError(f"{where}: port must be 1..65535 and threads >= 1, got {line.strip()!r}")
        hosts.append(Host(fields[0], port, threads))
    if not hosts:
        raise ValueError(f"{path}: no hosts listed")
    seen = set()
    for h in hosts:
        if (h.name, h.port) in seen:
            raise ValueError(f"{path}: {h.name}:{h.port} is listed twice (two peers on one host need two ports)")
        seen.add((h.name, h.port))
    return hosts


def _endpoint(scheme: str, host: str, port: int) -> str:
    return f"{scheme}/[{host}]:{port}" if ":" in host else f"{scheme}/{host}:{port}"


def remote_command(host: Host, rank: int, hosts: list[Host], run_id: str, config: str, args, remote_dir: str,
                   python: str, scheme: str = "tls") -> str:
    listen = _endpoint(scheme, args.listen_host or host.name, host.port)
    cmd = [python, "-m", "launch.cli", "peer", config, "--rank", str(rank), "--world", str(len(hosts)),
           "--run-id", run_id, "--listen", listen, "--timeout", str(args.timeout)]
    cmd += ["--tls-stdin"] if scheme == "tls" else ["--insecure"]
    for lower in hosts[:rank]:
        cmd += ["--zenoh", _endpoint(scheme, lower.name, lower.port)]
    threads = host.threads or args.threads
    if threads:
        cmd += ["--threads", str(threads)]
    if args.out is not None:
        cmd += ["--out", str(args.out)]
    cmd += run_options(args)
    if args.quiet or rank != 0:
        cmd.append("--quiet")
    return f"cd {shlex.quote(remote_dir)} && exec " + " ".join(shlex.quote(c) for c in cmd)


def run_hosts(config: Path, hosts_file: Path, args, out: Path) -> int:
    """Start one peer per host over ssh and watch them; ``out``: where this machine keeps the run's
    credentials (OUT/tls), and the peers' OUT (relative: to REMOTE_DIR). With ``args.restarts`` K,
    a lost peer restarts the run on the same hosts and ports (a new run id each time) from the
    newest checkpoint in OUT/checkpoints — as this machine sees it at REMOTE_DIR/OUT: a shared file
    system, or this machine as a host; else from the start — up to K times (launch/supervise.py)."""
    from nodes import security
    hosts = read_hosts(hosts_file)
    scheme = prepare_security(args, out, [[h.name] for h in hosts])
    ssh = shlex.split(args.ssh)
    remote_dir = args.remote_dir or str(Path.cwd())
    restarts = getattr(args, "restarts", 0) or 0
    log.info("%d peers on %s", len(hosts), ", ".join(f"{h.name}:{h.port}" for h in hosts))

    def start(attempt, resume, history):
        run_id = new_run_id()  # a peer we could not stop (on its host) can never join a later attempt
        log.info("run %s%s", run_id, f" (restart {len(history)})" if history else "")
        # a restart from a checkpoint: the peers read its scene (argparse takes --resume=DIR as one word)
        source = f"--resume={Path(out) / 'checkpoints' / Path(resume).name}" if resume is not None else str(config)
        run_args = supervise.resumed_args(args, resume)
        write_run_info(out, run_id, len(hosts), [_endpoint(scheme, h.name, h.port) for h in hosts], args)
        extra = supervise.peer_options(restarts, history)
        if args.checkpoint_every is not None:
            extra += ["--checkpoint-every", str(args.checkpoint_every)]
        for rank, host in enumerate(hosts):
            command = remote_command(host, rank, hosts, run_id, source, run_args, remote_dir, args.remote_python,
                                     scheme)
            command += " " + " ".join(shlex.quote(c) for c in extra)  # the command ends with exec PYTHON ...
            log.debug("peer %d: %s %s %s", rank, " ".join(ssh), host.name, command)
            proc = subprocess.Popen(ssh + [host.name, command], **supervise.popen_options())
            if scheme == "tls":  # its credentials, one JSON line; the pipe stays open while we run
                proc.stdin.write((security.load_identity(args.tls_dir, security.peer_name(rank)).to_json()
                                  + "\n").encode())
                proc.stdin.flush()
            attempt.add(proc)

    seen = Path(out) if Path(out).is_absolute() else Path(remote_dir) / out
    supervisor = supervise.Supervisor(start, restarts, seen / "checkpoints", local=False)
    try:
        return supervisor.run()
    except KeyboardInterrupt:
        _stop(supervisor.processes(), signal.SIGINT)
        raise
    finally:
        _stop(supervisor.processes(), signal.SIGTERM)
