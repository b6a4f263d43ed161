"""``sph run CONFIG --hosts FILE``: one peer per line of a hosts file, started over ssh.

Hosts file (``#`` starts a comment; rank = line order among the non-empty lines)::

    # host            port   [threads]
    node01.cluster    7447   16
    node02.cluster    7447   16
    10.0.0.7          7450

Peer R runs ``cd REMOTE_DIR && PYTHON -m launch.cli peer CONFIG --rank R ...`` on its host,
listening on ``tcp/LISTEN_HOST:PORT`` (``--listen-host``, default 0.0.0.0) and connecting to every lower rank's ``tcp/HOST:PORT`` (a full
mesh; no router, no multicast). The repository (and its environment) must be at REMOTE_DIR on
every host — a shared file system, or the same checkout everywhere. Rank 0 writes the outputs on
its host. The watch loop is the local launcher's: a failed peer stops the run, Ctrl-C stops all.
"""
from __future__ import annotations

import logging
import shlex
import signal
import subprocess
from dataclasses import dataclass
from pathlib import Path

from launch.local import _stop, _watch, new_run_id, run_options

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


def remote_command(host: Host, rank: int, hosts: list[Host], run_id: str, config: str, args, remote_dir: str,
                   python: str) -> str:
    cmd = [python, "-m", "launch.cli", "peer", config, "--rank", str(rank), "--world", str(len(hosts)),
           "--run-id", run_id, "--listen", f"tcp/{args.listen_host}:{host.port}", "--timeout", str(args.timeout)]
    for lower in hosts[:rank]:
        cmd += ["--connect", f"tcp/{lower.name}:{lower.port}"]
    threads = host.threads or args.threads
    if threads:
        cmd += ["--threads", str(threads)]
    if args.out is not None:
        cmd += ["--out", str(args.out)]
    cmd += run_options(args)
    if args.quiet or rank != 0:
        cmd.append("--quiet")
    return f"cd {shlex.quote(remote_dir)} && exec " + " ".join(shlex.quote(c) for c in cmd)


def run_hosts(config: Path, hosts_file: Path, args) -> int:
    hosts = read_hosts(hosts_file)
    run_id = new_run_id()
    ssh = shlex.split(args.ssh)
    remote_dir = args.remote_dir or str(Path.cwd())
    log.info("run %s: %d peers on %s", run_id, len(hosts), ", ".join(f"{h.name}:{h.port}" for h in hosts))
    procs = []
    try:
        for rank, host in enumerate(hosts):
            command = remote_command(host, rank, hosts, run_id, str(config), args, remote_dir, args.remote_python)
            log.debug("peer %d: %s %s %s", rank, " ".join(ssh), host.name, command)
            procs.append(subprocess.Popen(ssh + [host.name, command]))
        return _watch(procs)
    except KeyboardInterrupt:
        _stop(procs, signal.SIGINT)
        raise
    finally:
        _stop(procs, signal.SIGTERM)
