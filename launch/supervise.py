"""Watching a run's peer processes, and restarting a run that lost one.

The launchers (launch/local.py, launch/hosts.py) start one process per peer — the peer itself, or
the ssh client that runs it — each with a pipe as stdin (kept open: a peer started with
``--watch-stdin`` stops when it closes, so a killed launcher takes its peers down) and a pipe as
stdout (``--report-progress`` lines say how far each peer got; anything else is passed on).

``watch`` waits for the processes of one attempt. After the first failure the others get
``grace`` seconds to notice through Zenoh and exit by themselves; a process that is stopped
(SIGSTOP: it cannot notice anything) is killed at once, and any still running after the grace is
"not answering" and is stopped (SIGTERM with SIGCONT, then SIGKILL), so the launcher is out within
seconds of the first failure.

``Supervisor.run`` runs attempts until one succeeds: when a peer was lost (killed by a signal,
stopped or not answering, or the peers ended with the "peer lost" code 4) and restarts are left,
every process of the attempt is stopped and the run starts again, with the same number of peers,
from the newest complete checkpoint (or from the start if there is none yet). Results do not
depend on the decomposition, so the final state is bitwise the uninterrupted run's. Each restart
is logged and recorded (``history``; rank 0 of the last attempt writes it into summary.json).
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from nodes.supervise import PROGRESS

log = logging.getLogger("sph.launch")

EXIT_PEER = 4  # launch/cli.py EXIT_PEER: a peer was lost or timed out
EXIT_SSH = 255  # ssh: the connection failed, or the remote command was killed by a signal
GRACE_S = 3.0  # after a failure, how long the other peers have to stop by themselves
KILL_AFTER_S = 2.0  # after SIGTERM (or SIGINT), how long before SIGKILL


def popen_options() -> dict:
    """The pipes a supervised process gets (give them to subprocess.Popen)."""
    return {"stdin": subprocess.PIPE, "stdout": subprocess.PIPE}


def _signal_name(number: int) -> str:
    try:
        return signal.Signals(number).name
    except ValueError:
        return f"signal {number}"


def peer_options(restarts: int, history: list[dict]) -> list[str]:
    """The `sph peer` options of a supervised peer: stop when the launcher is gone, report progress,
    and (with restarts allowed) the restart history for summary.json."""
    cmd = ["--watch-stdin", "--report-progress"]
    if restarts:
        cmd += ["--restart-history", json.dumps(history, separators=(",", ":"))]
    return cmd


def resumed_args(args, resume: Path | None):
    """The launcher's options for an attempt that continues from checkpoint folder ``resume``: the
    checkpoint's own scene (no --set: it holds the resolved scene, run-time changes included)."""
    if resume is None:
        return args
    return argparse.Namespace(**dict(vars(args), resume=Path(resume), overrides=[]))


def describe_exit(code: int) -> str:
    if code < 0:
        return f"was killed by signal {-code} ({_signal_name(-code)})"
    if code == EXIT_PEER:
        return f"exited with code {code} (lost a peer or timed out)"
    if code == EXIT_SSH:
        return f"exited with code {code} (ssh: the connection failed, or the peer was killed by a signal)"
    return f"exited with code {code}"


def is_stopped(pid: int) -> bool:
    """Whether process ``pid`` of this machine is stopped (SIGSTOP, SIGTSTP, a debugger)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] in ("T", "t")


class Attempt:
    """The processes of one attempt, rank order; reads each one's stdout in a daemon thread."""

    def __init__(self):
        self.procs: list[subprocess.Popen] = []
        self.steps: dict[int, int] = {}  # rank -> the last step it reported
        self.started = time.time()
        self._threads = []

    def add(self, proc: subprocess.Popen):
        rank = len(self.procs)
        self.procs.append(proc)
        if proc.stdout is not None:
            thread = threading.Thread(target=self._read, args=(rank, proc.stdout), daemon=True)
            thread.start()
            self._threads.append(thread)

    def _read(self, rank: int, stream):
        for raw in stream:
            line = raw.decode(errors="replace")
            if line.startswith(PROGRESS + " "):
                try:
                    self.steps[rank] = int(line.split()[1])
                except (IndexError, ValueError):
                    pass
                continue
            try:
                sys.stdout.write(line)
                sys.stdout.flush()
            except (OSError, ValueError):
                pass  # our own stdout is gone: keep draining the pipe, so the peer never blocks on it

    def last_step(self) -> int | None:
        return max(self.steps.values(), default=None)

    def join_output(self, timeout: float = 1.0):
        """Let the reader threads pass on what the processes wrote before they ended."""
        deadline = time.monotonic() + timeout
        for thread in self._threads:
            thread.join(max(0.0, deadline - time.monotonic()))


@dataclass
class Lost:
    """The peer that was lost in an attempt, and how."""
    rank: int
    how: str                 # e.g. "was killed by signal 9 (SIGKILL)", "is stopped (SIGSTOP) and not answering"
    exit_code: int | None    # the process's exit code (negative: the signal), None if we had to stop it
    not_answering: bool = False


@dataclass
class Outcome:
    code: int                # 0, or the run's exit code (the first failing peer's; 4 for a signal)
    lost: Lost | None        # set when the run can be restarted (a peer was lost, nothing else failed)
    failures: dict           # rank -> exit code of every peer that failed by itself


def watch(procs, grace: float = GRACE_S, stopping: str = "the run", local: bool = True) -> Outcome:
    """Wait for every process of an attempt (see the module docstring); ``stopping`` names what a
    failure stops, for the log; ``local``: the processes are the peers themselves, so a stopped
    one can be seen in /proc (else they are ssh clients, and ssh's 255 means a lost peer too)."""
    lost_codes = (EXIT_PEER,) if local else (EXIT_PEER, EXIT_SSH)
    failures, first, not_answering = {}, None, {}
    stopped_by_us = set()
    while True:
        codes = [p.poll() for p in procs]
        now = time.monotonic()
        for rank, code in enumerate(codes):
            if code not in (None, 0) and rank not in failures and rank not in stopped_by_us:
                failures[rank] = code
                if first is None:
                    first = (rank, now)
                    log.error("peer %d %s; stopping %s", rank, describe_exit(code), stopping)
                else:
                    log.info("peer %d %s", rank, describe_exit(code))
        running = [r for r, c in enumerate(codes) if c is None]
        if not running:
            break
        if first is not None:
            frozen = [r for r in running if local and is_stopped(procs[r].pid)]
            for r in frozen:  # it cannot notice anything: no point waiting for it
                log.error("peer %d is stopped (SIGSTOP) and not answering; killing it", r)
                not_answering[r] = "is stopped (SIGSTOP) and not answering"
            late = [r for r in running if r not in frozen] if now - first[1] > grace else []
            if late:
                log.error("peer%s %s still running %.0f s after peer %d %s: not answering; stopping %s",
                          "s" if len(late) > 1 else "", ", ".join(map(str, late)), grace, first[0],
                          describe_exit(failures[first[0]]), "them" if len(late) > 1 else "it")
                for r in late:
                    not_answering[r] = (f"was not answering (still running {grace:.0f} s after peer {first[0]} "
                                        f"{describe_exit(failures[first[0]])})")
            if frozen or late:
                stop([procs[r] for r in frozen], signal.SIGKILL)
                stop([procs[r] for r in late], signal.SIGTERM)
                stopped_by_us.update(frozen + late)
        time.sleep(0.05)
    if first is None:
        return Outcome(0, None, {})
    first_code = failures[first[0]]
    code = first_code if first_code > 0 else EXIT_PEER
    if any(c > 0 and c not in lost_codes for c in failures.values()):
        return Outcome(code, None, failures)  # a peer failed by itself (bad input, unphysical, a bug)
    killed = [r for r, c in failures.items() if c < 0 or c == EXIT_SSH]
    if killed:
        lost = Lost(killed[0], describe_exit(failures[killed[0]]), failures[killed[0]])
    elif not_answering:
        rank = next(iter(not_answering))
        lost = Lost(rank, not_answering[rank], None, not_answering=True)
    else:  # every failed peer says it lost another (a network cut, a timeout)
        lost = Lost(first[0], describe_exit(first_code), first_code)
    return Outcome(code, lost, failures)


def stop(procs, sig=signal.SIGTERM, kill_after: float = KILL_AFTER_S):
    """Send ``sig`` to every process still running (with SIGCONT, so that a stopped one gets it
    too), SIGKILL those still there ``kill_after`` seconds later, and reap them all."""
    for p in procs:
        if p.poll() is None:
            try:
                p.send_signal(sig)
                if sig != signal.SIGKILL:
                    p.send_signal(signal.SIGCONT)
            except ProcessLookupError:
                pass
    deadline = time.monotonic() + kill_after
    for p in procs:
        try:
            p.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
        if p.stdin is not None and not p.stdin.closed:
            try:  # end-of-file for whatever still reads it (a peer behind a killed ssh stand-in)
                p.stdin.close()
            except OSError:
                pass


class Supervisor:
    """Runs a run's attempts until one succeeds or no restart is left.

    ``start(attempt, resume, history)`` starts the processes of one attempt (``attempt.add``
    each, rank order): ``resume`` is the checkpoint folder to continue from (None: the run's own
    start), ``history`` the restarts so far (JSON-able dicts, see ``peer_options``).
    ``checkpoints``: the run's OUT/checkpoints as this machine sees it (None or absent: every
    restart is from the start); ``origin_step``: the step the run's own start is (a --resume run's)."""

    def __init__(self, start, restarts: int, checkpoints: Path | None, local: bool = True,
                 grace: float = GRACE_S, origin_step: int = 0):
        self.start, self.restarts, self.checkpoints = start, restarts, checkpoints
        self.local, self.grace, self.origin_step = local, grace, origin_step
        self.history: list[dict] = []
        self.attempt: Attempt | None = None
        self._before = None

    def processes(self) -> list:
        return self.attempt.procs if self.attempt is not None else []

    def run(self) -> int:
        # a checkpoint already there is an earlier run's (the same OUT folder): never restart from it
        self._before = self._newest_checkpoint()
        resume = None
        while True:
            left = self.restarts - len(self.history)
            self.attempt = Attempt()
            self.start(self.attempt, resume, list(self.history))
            outcome = watch(self.attempt.procs, self.grace, "this attempt" if left else "the run", self.local)
            stop(self.attempt.procs, signal.SIGTERM)
            ended = time.time()
            self.attempt.join_output()
            if outcome.code == 0:
                return 0
            if outcome.lost is None:
                return outcome.code
            lost = outcome.lost
            found = self._newest_checkpoint()
            if found is not None and self._before is not None and found[::2] == self._before[::2]:
                found = None
            # the peers report a few times a second; a checkpoint was reached by all of them
            reached = [s for s in (self.attempt.last_step(), found[1] if found else None) if s is not None]
            step = max(reached) if reached else None
            at = f"at ~step {step}" if step is not None else "before any step"
            if left <= 0:
                if self.restarts:
                    log.error("peer %d %s %s; no restart left (%d used); the run stops", lost.rank, lost.how, at,
                              self.restarts)
                return outcome.code
            resume = found[0] if found else None
            entry = {
                "restart": len(self.history) + 1, "peer": lost.rank, "how": lost.how,
                "exit_code": lost.exit_code, "signal": -lost.exit_code if (lost.exit_code or 0) < 0 else None,
                "not_answering": lost.not_answering, "step": step,
                "resumed_from_step": found[1] if found else self.origin_step,
                "checkpoint": str(found[0]) if found else None,
                "attempt_wall_s": round(ended - self.attempt.started, 3),
                "wall_s_lost": round(ended - max(self.attempt.started, found[2] if found else 0.0), 3),
                "note": "wall_s_lost: from the checkpoint resumed from (or the attempt's start, if later) to "
                        "the end of the failed attempt; the restart's start-up comes on top",
            }
            self.history.append(entry)
            where = (f"checkpoint step {found[1]}" if found else
                     f"the run's start, step {self.origin_step} (no checkpoint of this run yet)")
            log.warning("peer %d %s %s; restarting from %s (restart %d of %d)", lost.rank, lost.how, at, where,
                        entry["restart"], self.restarts)
            if self.checkpoints is not None:
                from sphcore import checkpoint
                checkpoint.remove_partial(self.checkpoints)

    def _newest_checkpoint(self):
        """(folder, step, commit time) of the newest complete checkpoint, or None."""
        if self.checkpoints is None:
            return None
        from sphcore import checkpoint
        found = checkpoint.latest(self.checkpoints)
        if found is None:
            return None
        folder, step = found
        try:
            committed = os.stat(folder / "manifest.json").st_mtime
        except OSError:
            committed = 0.0
        return folder, step, committed
