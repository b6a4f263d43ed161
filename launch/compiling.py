"""Progress while numba compiles: the first run of a scene compiles its kernels for minutes (4 min on a
loaded 2-core machine), and without a word that looks like a hang.

``report_compiling()`` installs a numba event listener (``numba:compile``), so a process that compiles
says so — "compiling kernels for this scene (first run only)" — then the elapsed time every
``every`` seconds while it goes on, and the total when it is done. Every process that compiles
(sph run, each peer, the viewer) reports for itself. numba also fires the event, briefly, for the
literal dispatch of cached kernels (backends/literal.py: the non-literal attempt fails typing, then
the cached literal version loads; about 4 s in all for configs/tiny.toml), so nothing is said until
compilation has gone on for ``announce_after`` seconds: a run whose kernels are cached prints nothing.
"""
from __future__ import annotations

import logging
import threading
import time

log = logging.getLogger("sph.compile")

START = "compiling kernels for this scene (first run only)"


class CompileProgress:
    """Listener for numba's ``numba:compile`` events (nested compilations count once)."""

    def __init__(self, say=None, every: float = 15.0, quiet_after: float = 3.0, announce_after: float = 8.0):
        self.say = say or log.info
        self.every, self.quiet_after, self.announce_after = every, quiet_after, announce_after
        self._announced = False
        self._depth = 0
        self._started = None     # perf_counter() of the first compilation of the current burst
        self._last_end = None
        self._lock = threading.Lock()

    def on_start(self, event=None):
        with self._lock:
            self._depth += 1
            if self._started is not None:
                return
            self._started = time.perf_counter()
            self._announced = False
        threading.Thread(target=self._tick, name="sph-compile-progress", daemon=True).start()

    def on_end(self, event=None):
        with self._lock:
            self._depth = max(0, self._depth - 1)
            self._last_end = time.perf_counter()

    def at_exit(self):
        """A process that ends right after compiling (before the quiet time) still says it finished."""
        with self._lock:
            if self._started is None or self._last_end is None or self._depth or not self._announced:
                return
            took, self._started = self._last_end - self._started, None
        self.say(f"kernels compiled in {took:.0f} s (cached for the next runs)")

    def _tick(self):
        next_report = self._started + self.every
        while True:
            time.sleep(min(0.25, self.every / 4))
            with self._lock:
                if self._started is None:  # reported at exit
                    return
                now = time.perf_counter()
                if self._depth == 0 and self._last_end is not None and now - self._last_end > self.quiet_after:
                    took, self._started, announced = self._last_end - self._started, None, self._announced
                    break
                elapsed = now - self._started
                announce = not self._announced and elapsed >= self.announce_after
                self._announced = self._announced or announce
                due = self._announced and not announce and now >= next_report
            if announce:
                self.say(f"{START} ...")
            if due:
                self.say(f"compiling kernels: {elapsed:.0f} s so far")
                next_report += self.every
        if announced:
            self.say(f"kernels compiled in {took:.0f} s (cached for the next runs)")


def report_compiling(every: float = 15.0, say=None, announce_after: float = 8.0) -> CompileProgress:
    """Install the progress reporter for this process's numba compilations; returns it."""
    from numba.core import event

    progress = CompileProgress(say, every, announce_after=announce_after)

    class _Listener(event.Listener):
        def on_start(self, ev):
            progress.on_start(ev)

        def on_end(self, ev):
            progress.on_end(ev)

    event.register("numba:compile", _Listener())
    import atexit
    atexit.register(progress.at_exit)
    return progress
