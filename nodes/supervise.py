"""A process started by a launcher follows its launcher: it stops when the launcher is gone, and
tells the launcher how far it has got.

A launcher (``sph run --peers N``, ``sph run --hosts FILE``) gives each process a pipe as stdin
and keeps its end open for the process's whole life. The kernel closes that end when the launcher
dies, however it dies (kill -9 included), so the process reads end-of-file: ``watch_stdin`` sees
it in a daemon thread and stops the process. Over ssh the same holds: the remote command's stdin
closes when the ssh client goes. Something else may read first lines from ``sys.stdin`` before
(credentials, one JSON line): the watcher reads whatever follows, through the same buffered
stream, until end-of-file.

``ProgressReport`` writes ``sph-progress STEP`` lines on stdout, at most a few a second, which the
launcher reads (launch/supervise.py) to say at about which step a peer was lost.
"""
from __future__ import annotations

import logging
import os
import sys
import threading
import time

log = logging.getLogger("sph.supervise")

PROGRESS = "sph-progress"  # the first word of a progress line on a supervised process's stdout


def watch_stdin(on_eof, stream=None) -> threading.Thread:
    """Call ``on_eof()`` (from a daemon thread) once ``stream`` (default ``sys.stdin``) reaches
    end-of-file; lines read before that are ignored. Returns the thread."""
    stream = sys.stdin if stream is None else stream

    def watch():
        try:
            while stream.readline():
                pass
        except (OSError, ValueError) as e:  # a closed or unreadable stdin: the launcher is gone too
            log.debug("stdin: %s", e)
        on_eof()

    thread = threading.Thread(target=watch, name="watch-stdin", daemon=True)
    thread.start()
    return thread


def exit_when_launcher_gone(who: str, code: int):
    """The ``on_eof`` of a peer: say so and end the process at once (its Zenoh session and sockets
    close with it; the other peers of the run stop the same way)."""
    def on_eof():
        log.error("%s: the launcher is gone (stdin closed); stopping", who)
        logging.shutdown()
        os._exit(code)
    return on_eof


class ProgressReport:
    """``report(step)`` after each step: a ``sph-progress STEP`` line on ``stream`` (default
    stdout) at most every ``every_s`` seconds."""

    def __init__(self, stream=None, every_s: float = 0.1):
        self.stream = sys.stdout if stream is None else stream
        self.every_s = every_s
        self._last = -float("inf")

    def __call__(self, step: int, force: bool = False):
        now = time.monotonic()
        if not force and now - self._last < self.every_s:
            return
        self._last = now
        try:
            self.stream.write(f"{PROGRESS} {int(step)}\n")
            self.stream.flush()
        except (OSError, ValueError):  # nobody reads any more (the launcher is gone): not our problem
            pass
