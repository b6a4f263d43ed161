"""How long N processes take to step a scene from an empty kernel cache when they start at once (the
peers of a run started cold): with the compile lock (backends/literal.py) one compiles each kernel
and the others load it. Each process steps configs/tiny.toml 3 times in float64; prints each
process's seconds and the wall time of all.

    .venv/bin/python scripts/investigations/compile_among_processes.py [--processes 4]

Measured 2026-12-06 (2 cores): 4 processes 63-65 s with the lock, 123 s without it (bff70d0^, run from a worktree)
(docs/BENCHMARKS.md, "Test suite").
"""
import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
STEP = """
import time
t = time.time()
from sphcore.scene import load_scene
from sphcore.solver import Simulation
sim = Simulation(load_scene('configs/tiny.toml'), 'f64')
for _ in range(3):
    sim.step()
print(f"{time.time() - t:.1f}")
"""


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--processes", type=int, default=4)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, SPH_CACHE_DIR=cache)
        env.pop("NUMBA_CACHE_DIR", None)
        start = time.perf_counter()
        runs = [subprocess.Popen([sys.executable, "-c", STEP], cwd=ROOT, env=env, stdout=subprocess.PIPE, text=True)
                for _ in range(args.processes)]
        seconds = [run.communicate()[0].strip() for run in runs]
        print(f"{args.processes} processes from an empty cache: {', '.join(seconds)} s each; "
              f"{time.perf_counter() - start:.1f} s wall")


if __name__ == "__main__":
    main()
