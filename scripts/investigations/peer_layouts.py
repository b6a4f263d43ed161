"""The automatic layout of a scene's peers (nodes.peer.decomposition_for) for several peer counts:
the blocks chosen, the busiest peer's starting particles, how many peers start empty, the particles
near a cut (decomposition.halo_particles); and any layouts given with --dims for comparison.

    .venv/bin/python scripts/investigations/peer_layouts.py [--scene configs/dam_break.toml]
        [--peers 2 4 16 64] [--dims 16,1,4 ...]
"""
import argparse

import numpy as np

from nodes.peer import decomposition_for
from sphcore.decomposition import Decomposition, halo_particles
from sphcore.scene import load_scene
from sphcore.solver import Simulation


def describe(label, dec, cells, n_peers):
    counts = np.bincount(dec.owner(cells), minlength=n_peers)
    hist = [np.bincount(cells[:, a], minlength=dec.ncell[a]) for a in range(3)]
    print(f"{label:>22}  blocks {'x'.join(map(str, dec.dims)):>8}  busiest {counts.max():>7}  "
          f"empty {np.count_nonzero(counts == 0):>4} of {n_peers:<4}  near a cut {halo_particles(dec, hist):>8.0f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="configs/dam_break.toml")
    ap.add_argument("--peers", type=int, nargs="+", default=[2, 3, 4, 8, 16, 64])
    ap.add_argument("--dims", nargs="*", default=["16,1,4"], help="layouts to compare, as px,py,pz")
    a = ap.parse_args()
    scene = load_scene(a.scene, [])
    sim = Simulation(scene, "f32")
    cells = sim.grid.cells_of(sim.state.x)
    ncell = tuple(int(n) for n in sim.grid.ncell)
    print(f"{a.scene}: {len(cells)} particles, {ncell} cells, {sim.grid.reach} cells a support radius")
    for n in a.peers:
        describe(f"{n} peers, automatic", decomposition_for(scene, sim.grid, n, sim.state.x), cells, n)
    for text in a.dims:
        dims = tuple(int(v) for v in text.split(","))
        n = int(np.prod(dims))
        describe(f"{n} peers, given", Decomposition.balanced(ncell, dims, cells, reach=sim.grid.reach), cells, n)


if __name__ == "__main__":
    main()
