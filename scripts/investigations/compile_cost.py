"""What does one more scene choice cost the cold test suite in compiling?

Runs two steps of configs/tiny.toml once per configuration, in order, in one fresh numba cache, each
in its own process; prints each run's wall time and the count of compiled specialisations the cache
then holds. A run pays only for the drivers the runs before it did not compile, so the second and
later figures are the price of that one choice (docs/BENCHMARKS.md, "Test suite").

    .venv/bin/python scripts/investigations/compile_cost.py
    .venv/bin/python scripts/investigations/compile_cost.py --cache /tmp/cc --run f64 --run "f64 sph.kernel='cubic_spline'"
    .venv/bin/python scripts/investigations/compile_cost.py --run f64 --functions    # seconds per driver
"""
import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RUNS = ["f64", "f64 sph.kernel='cubic_spline'", "f32"]
STEP = ("import sys; from sphcore.scene import load_scene; from sphcore.solver import Simulation; "
        "sim = Simulation(load_scene('configs/tiny.toml', sys.argv[2:]), sys.argv[1]); sim.step(); sim.step()")
# With --functions: numba's compile events, each top-level compile's function and seconds (a driver
# the helper process compiles counts in full: sphcore/backends/literal.py wraps the wait in its event)
LISTEN = """
import time
from numba.core import event
_stack = []
class _Each(event.Listener):
    def on_start(self, ev):
        _stack.append(time.perf_counter())
    def on_end(self, ev):
        took = time.perf_counter() - _stack.pop()
        if not _stack and took >= 0.3:
            f = ev.data["dispatcher"].py_func
            print(f"    {took:6.1f} s  {f.__module__.rsplit('.', 1)[-1]}.{f.__qualname__}", flush=True)
event.register("numba:compile", _Each())
"""


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", help="numba cache folder to start empty (default: a temporary one)")
    ap.add_argument("--functions", action="store_true", help="also print each compiled function's seconds "
                    "(those over 0.3 s)")
    ap.add_argument("--run", action="append", help="precision then --set overrides, e.g. \"f32 sph.kernel='muller'\" "
                    f"(repeatable; default: {RUNS})")
    args = ap.parse_args()
    cache = Path(args.cache) if args.cache else Path(tempfile.mkdtemp(prefix="compile_cost-"))
    if cache.exists() and any(cache.iterdir()):
        sys.exit(f"compile_cost: --cache {cache} is not empty; the figures need an empty cache")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    try:
        for run in args.run or RUNS:
            t = time.perf_counter()
            code = (LISTEN if args.functions else "") + STEP
            subprocess.run([sys.executable, "-c", code, *run.split()], cwd=ROOT, env=env, check=True)
            n = sum(1 for _ in cache.rglob("*.nbc"))
            print(f"{run:40s} {time.perf_counter() - t:6.1f} s   cache: {n} specialisations", flush=True)
    finally:
        if not args.cache:
            shutil.rmtree(cache, ignore_errors=True)


if __name__ == "__main__":
    main()
