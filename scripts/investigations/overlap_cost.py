"""What splitting the passes into interior and boundary rows costs when nothing travels: two peers of
the 3D dam break in one process (the in-process transport delivers at once, so no latency is hidden),
with decomposition.overlap on and off, stepped in turn (ABAB...), one numba thread.

    .venv/bin/python scripts/investigations/overlap_cost.py [--spacing 0.0185] [--rounds 4] [--steps 30]

Prints ms per step of both peers together for each round, and each peer's interior fraction."""
import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

import numba  # noqa: E402

from nodes.cluster import InProcessCluster  # noqa: E402
from sphcore.scene import load_scene  # noqa: E402


def cluster(spacing: float, overlap: bool):
    sc = load_scene(ROOT / "configs" / "dam_break.toml",
                    [f"particles.spacing={spacing}", f"decomposition.overlap={'true' if overlap else 'false'}",
                     "time.mode='fixed'", "time.dt=1e-4"])
    c = InProcessCluster(sc, 2, "f32", dims=(2, 1, 1))
    for _ in range(3):  # compiled, and the first steps' allocations done
        c.step()
    return c


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spacing", type=float, default=0.0185)
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--steps", type=int, default=30)
    args = ap.parse_args()
    numba.set_num_threads(1)
    runs = {True: cluster(args.spacing, True), False: cluster(args.spacing, False)}
    print(f"{sum(p.state.n_owned for p in runs[True].peers)} particles over 2 peers in one process, 1 thread")
    ms = {True: [], False: []}
    for _ in range(args.rounds):
        for overlap, c in runs.items():
            t = time.perf_counter()
            for _ in range(args.steps):
                c.step()
            ms[overlap].append((time.perf_counter() - t) / args.steps * 1e3)
    for overlap in (True, False):
        print(f"{'overlap' if overlap else 'no overlap':>10}: " + " ".join(f"{v:.1f}" for v in ms[overlap])
              + " ms per step")
    print("interior fraction per peer: " + ", ".join(
        f"{h.overlapped_rows / max(1, h.overlapped_rows + h.after_rows):.2f}" for h in runs[True].halos))


if __name__ == "__main__":
    main()
