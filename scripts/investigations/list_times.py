"""The skin's two list passes timed alone: the `sph bench --until` DFSPH case (the 3D dam break,
49,152 particles, f32, 2 threads, the automatic skin of 0.45) stepped 60 steps, then the filter of
the candidates (median of 20 calls) and the build of the candidates from the reference positions
(median of 10 calls), ms.

    .venv/bin/python scripts/investigations/list_times.py [--steps 60] [--threads 2]

The chunked compress-stores (sphcore/simd.py) are on wherever numba compiles for AVX-512; for the
scalar loop with AVX-512 on, run it in a worktree of b120f3c (PYTHONPATH=the worktree), alternating
(docs/BENCHMARKS.md, 2026-12-07 late morning)."""
import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from scripts.investigations.dfsph_stage_times import stepped_case  # noqa: E402
from scripts.investigations.peer_pass_cost import median_ms  # noqa: E402
from sphcore import grid as grid_module  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    _, sim = stepped_case(args.steps, args.threads)
    grid, n, state = sim.grid, sim.state.n_owned, sim.state
    print(f"{n} particles after {args.steps} steps, {args.threads} threads, AVX-512 chunks: "
          f"{getattr(grid_module, 'AVX512', False)}; {grid.cand_counts[:n].mean():.1f} candidates and "
          f"{grid.counts[:n].mean():.1f} neighbours a row")
    filter_ms = median_ms(lambda: grid.filter_neighbours(state.x, n), repeat=20)
    build_ms = median_ms(lambda: grid.build_candidates(state.extra["x_ref"], n), repeat=10)
    print(f"filter {filter_ms:.2f} ms  build {build_ms:.2f} ms")


if __name__ == "__main__":
    main()
