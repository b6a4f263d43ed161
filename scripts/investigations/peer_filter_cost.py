"""The neighbour-list filter's cost per candidate tested (ns), timed inside every process of a run:
one process of 24,576 particles alone, two such processes at once, and 2 peers of the bench's 49,152
particles with and without overlap (``decomposition.overlap``). docs/BENCHMARKS.md, "Two peers: the
filter is slower while a halo travels".

    .venv/bin/python scripts/investigations/peer_filter_cost.py [--rounds 2] [--steps 400]

The timer wraps ``Grid.filter_neighbours`` through a ``sitecustomize`` module put first on PYTHONPATH
(the peers inherit it); each process writes its total to a file at exit. About a minute a round.
"""
import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SITE = '''
import atexit, os, time
from sphcore import grid as _g
_filter, _total = _g.Grid.filter_neighbours, [0.0, 0]

def filter_neighbours(self, x, n_query, rows=None):
    t0 = time.perf_counter()
    out = _filter(self, x, n_query, rows)
    _total[0] += time.perf_counter() - t0
    _total[1] += int(self.cand_counts[:n_query].sum() if rows is None else self.cand_counts[rows].sum())
    return out

_g.Grid.filter_neighbours = filter_neighbours
atexit.register(lambda: _total[1] and open(os.path.join(os.environ["FILTER_COST_DIR"], f"{os.getpid()}.txt"),
                                           "w").write(f"{1e9 * _total[0] / _total[1]:.3f}"))
'''
BENCH_DX = 0.012428930023815439  # the bench's 49,152 particles
HALF_DX = 0.01566                # 24,576 particles: one peer's share


def run(out: Path, peers: int, dx: float, overlap: bool, steps: int):
    return subprocess.Popen(
        [sys.executable, "-m", "launch.cli", "run", str(ROOT / "configs" / "dam_break.toml"), "--peers", str(peers),
         "--threads", "1", "--steps", str(steps), "--precision", "f32", "--no-viewer", "--quiet", "--out", str(out),
         "--set", f"particles.spacing={dx}", "--set", "time.mode='fixed'", "--set", "time.dt=0.0001",
         "--set", f"decomposition.overlap={str(overlap).lower()}"],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--steps", type=int, default=400)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        site, results = Path(tmp, "site"), Path(tmp, "results")
        site.mkdir()
        (site / "sitecustomize.py").write_text(SITE)
        os.environ["PYTHONPATH"] = os.pathsep.join([str(site), str(ROOT), os.environ.get("PYTHONPATH", "")])
        os.environ["FILTER_COST_DIR"] = str(results)
        cases = {"one process of 24,576 alone": [(1, HALF_DX, True)],
                 "two such processes at once": [(1, HALF_DX, True), (1, HALF_DX, True)],
                 "2 peers, overlap": [(2, BENCH_DX, True)], "2 peers, no overlap": [(2, BENCH_DX, False)]}
        for r in range(args.rounds):
            for name, runs in cases.items():
                results.mkdir()
                procs = [run(Path(tmp, f"run{k}"), *spec, args.steps) for k, spec in enumerate(runs)]
                codes = [p.wait() for p in procs]
                # the launcher of a multi-peer run writes no figure: it runs no filter
                figures = sorted(f.read_text() for f in results.iterdir())
                print(f"round {r + 1}: {name:30s} ns per candidate: {', '.join(figures)}"
                      + ("" if codes == [0] * len(codes) else f"  (exit codes {codes})"), flush=True)
                for f in results.iterdir():
                    f.unlink()
                results.rmdir()


if __name__ == "__main__":
    main()
