"""DFSPH's passes one by one: the `sph bench --until` DFSPH case (the 3D dam break, 49,152 particles,
f32, 2 threads, the automatic skin) stepped 60 steps, then each pass called again and again on the
arrays of that step: the density pass (with the stored m_j grad W_ij), the factor, one source and
one update of the divergence solve, the forces pass and the lists' filter. Medians of 30 calls, ms.

    .venv/bin/python scripts/investigations/dfsph_stage_times.py [--steps 60] [--threads 2]

To compare two commits, run it in a worktree of each (PYTHONPATH=the worktree), alternating."""
import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

import numba  # noqa: E402

from launch import bench  # noqa: E402
from scripts.investigations.peer_pass_cost import median_ms  # noqa: E402
from sphcore import stages as st  # noqa: E402
from sphcore.scene import load_scene  # noqa: E402
from sphcore.solver import Simulation  # noqa: E402

SCENE = ROOT / "configs" / "dam_break.toml"
SPACING = 0.012428930023815439  # the bench's 49,152 particles


def stepped_case(steps: int, threads: int):
    """(scene, Simulation) of the `sph bench --until` DFSPH case after ``steps`` steps on ``threads``."""
    numba.set_num_threads(threads)
    scene = load_scene(SCENE, bench._until_overrides(SCENE, SPACING, "dfsph") + ["run.neighbour_skin=-1.0"])
    sim = Simulation(scene, "f32")
    for _ in range(steps):
        sim.step()
    return scene, sim


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    scene, sim = stepped_case(args.steps, args.threads)
    e, prm, f = sim.engine, sim.prm_now, sim.dtype.type
    on = {"v": "v"}  # the divergence solve's velocities
    passes = {
        "density": lambda: e.run(st.DENSITY, prm=prm, dt_prev=f(sim.dt_prev), commit=False),
        "factor": lambda: e.run(st.DFSPH_FACTOR, prm=prm),
        "source": lambda: e.run(st.DFSPH_SOURCE, arrays=on, prm=prm, divergence=1, dt=f(sim.dt), share=f(1.0),
                                rho_ref=f(scene.fluid.rest_density)),
        "update": lambda: e.run(st.DFSPH_UPDATE, arrays=on, prm=prm, inv_dt=f(1.0 / sim.dt)),
        "forces": lambda: e.run(st.FORCES, prm=prm),
        "filter": lambda: sim.grid.filter_neighbours(sim.state.x, sim.state.n_owned),
    }
    print(f"{sim.n_particles} particles after {args.steps} steps, {args.threads} threads; ms, median of 30:")
    print("  ".join(f"{name} {median_ms(run, repeat=30):.2f}" for name, run in passes.items()))


if __name__ == "__main__":
    main()
