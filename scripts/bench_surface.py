"""The live surface's cost (docs/BENCHMARKS.md "Live surface"): for the 3D dam break at each spacing
given, the mean step (10 steps after 5), the peer's part (nodes.frames.surface_piece: the colour
field on the lattice) and the viewer's (Viewer._log_surface: assembling and meshing), 3 calls each.

    .venv/bin/python scripts/bench_surface.py 0.025 0.0125 0.0078
"""
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from nodes.frames import domain_box, surface_lattice, surface_piece  # noqa: E402
from nodes.viewer import Viewer  # noqa: E402
from sphcore.scene import load_scene  # noqa: E402
from sphcore.solver import Simulation  # noqa: E402

CONFIG = Path(__file__).resolve().parent.parent / "configs" / "dam_break.toml"


class Discard:
    """A Rerun stream that drops what it is given: only the viewer's own work is timed."""

    def log(self, *args, **kwargs):
        pass

    set_time = send_blueprint = flush = disconnect = log


def main(spacings):
    for spacing in spacings:
        scene = load_scene(CONFIG, [f"particles.spacing={spacing}"])
        sim = Simulation(scene, "f32")
        for _ in range(5):
            sim.step()
        t = time.perf_counter()
        for _ in range(10):
            sim.step()
        step_ms = (time.perf_counter() - t) / 10 * 1e3
        box = domain_box(scene)
        lattice = surface_lattice(scene, box, sim.n_particles)
        piece = surface_piece(sim, lattice, None)  # (compiles on a first run)
        t = time.perf_counter()
        for _ in range(3):
            piece = surface_piece(sim, lattice, None)
        peer_ms = (time.perf_counter() - t) / 3 * 1e3
        viewer = Viewer(scene, box, Discard(), world=1, particles=sim.n_particles)
        viewer._log_surface([piece])
        t = time.perf_counter()
        for _ in range(3):
            size = viewer._log_surface([piece])
        view_ms = (time.perf_counter() - t) / 3 * 1e3
        viewer.close()
        print(f"{sim.n_particles} particles: step {step_ms:.1f} ms, peer surface {peer_ms:.1f} ms, viewer "
              f"{view_ms:.1f} ms, mesh {size / 1e6:.2f} MB, lattice step {lattice[1] / spacing:.2f} spacings",
              flush=True)


if __name__ == "__main__":
    main([float(a) for a in sys.argv[1:]] or [0.025, 0.0125])
