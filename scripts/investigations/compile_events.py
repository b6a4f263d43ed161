"""Where does a scene's first run spend its compiling? Compiles one step of a scene in this process
(NUMBA_DISABLE_CACHE=1: nothing loaded from numba's cache, no compile helper) and prints each
compiled function's own seconds (nested compiles subtracted), its total, and how often it compiled
(docs/BENCHMARKS.md, "Test suite", 2026-12-07 afternoon: the list builder 18.8 s, then 7.2 s).

    .venv/bin/python scripts/investigations/compile_events.py configs/dam_break.toml [f64|f32]
    SPH_FASTER_COMPILE=0 .venv/bin/python scripts/investigations/compile_events.py configs/dam_break.toml
"""
import os
import sys

os.environ["NUMBA_DISABLE_CACHE"] = "1"  # before numba is imported

import collections  # noqa: E402
import time  # noqa: E402

from numba.core import event  # noqa: E402

_stack = []
own, total, count = collections.Counter(), collections.Counter(), collections.Counter()


class _Each(event.Listener):
    def on_start(self, ev):
        _stack.append([time.perf_counter(), 0.0])

    def on_end(self, ev):
        started, nested = _stack.pop()
        took = time.perf_counter() - started
        f = ev.data["dispatcher"].py_func
        name = f"{f.__module__.rsplit('.', 1)[-1]}.{f.__qualname__}"
        own[name] += took - nested
        total[name] += took
        count[name] += 1
        if _stack:
            _stack[-1][1] += took


def main():
    from sphcore.scene import load_scene
    from sphcore.solver import Simulation
    event.register("numba:compile", _Each())
    started = time.perf_counter()
    Simulation(load_scene(sys.argv[1], []), sys.argv[2] if len(sys.argv) > 2 else "f64").step()
    print(f"one step, compiling included: {time.perf_counter() - started:.1f} s")
    for name, s in own.most_common(25):
        print(f"  {s:7.2f} s own  {total[name]:7.2f} s total  x{count[name]}  {name}")


if __name__ == "__main__":
    main()
