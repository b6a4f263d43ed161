"""3D dam break in PySPH (WCSPH scheme, OpenMP), timed for ``sph bench``.

Standalone script: run it with the interpreter of the venv that has ``pysph``
installed (see ``scripts/setup_bench.sh``).  Prints ONE line of JSON to stdout;
PySPH's own messages go to stderr.

The scene mirrors our ``dam_break.toml``: tank [0,1.6]x[0,0.6]x[0,0.6] (y up),
water column [0,0.4]x[0,0.4]x[0,0.6] on a cubic lattice at (i+0.5)*dx, rest
density 1000, gravity -9.81 in y, Tait EOS (gamma 7, c0 = 10 sqrt(2 g H)),
fixed time step.  PySPH needs boundary particles: the tank walls and floor
(no lid) are ``--boundary-layers`` lattice layers of solid particles just
outside the tank, on the same lattice as the fluid.  By default h = 1.15 dx
with the Wendland quintic kernel (support 2h = 2.3 dx, as in our code).

PySPH generates and compiles Cython code at set-up; by default the compile
cache goes into the temp dir (so every run recompiles, ~1 min, not timed).
Only the stepping loop is timed: from the end of the first (warm-up) step to
the end of ``steps`` further steps.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import tempfile
import time

TANK = (1.6, 0.6, 0.6)
COLUMN = (0.4, 0.4, 0.6)
RHO0 = 1000.0
G = 9.81
GAMMA = 7.0
C0 = 10.0 * math.sqrt(2.0 * G * COLUMN[1])  # ~28 m/s


def make_particles(dx: float, hdx: float, layers: int):
    import numpy as np
    from pysph.base.utils import get_particle_array_wcsph

    n = [int(round(L / dx)) for L in COLUMN]
    i, j, k = np.mgrid[0:n[0], 0:n[1], 0:n[2]]
    xf = (i.ravel() + 0.5) * dx
    yf = (j.ravel() + 0.5) * dx
    zf = (k.ravel() + 0.5) * dx

    nt = [int(round(L / dx)) for L in TANK]
    i, j, k = np.mgrid[-layers:nt[0] + layers, -layers:nt[1],
                       -layers:nt[2] + layers]
    i, j, k = i.ravel(), j.ravel(), k.ravel()
    outside = (i < 0) | (i >= nt[0]) | (j < 0) | (k < 0) | (k >= nt[2])
    xb = (i[outside] + 0.5) * dx
    yb = (j[outside] + 0.5) * dx
    zb = (k[outside] + 0.5) * dx

    h0 = hdx * dx
    m0 = RHO0 * dx ** 3
    fluid = get_particle_array_wcsph(name="fluid", x=xf, y=yf, z=zf)
    boundary = get_particle_array_wcsph(name="boundary", x=xb, y=yb, z=zb)
    for pa in (fluid, boundary):
        pa.m[:] = m0
        pa.h[:] = h0
        pa.rho[:] = RHO0
    return fluid, boundary


def run(dx: float, steps: int, threads: int, hdx: float, layers: int,
        dt: float | None, integrator: str, alpha: float,
        cache_dir: str | None) -> dict:
    if dt is None:
        dt = 1.0e-4 * dx / 0.0125  # same CFL number at every resolution
    tmp = tempfile.mkdtemp(prefix="sph_bench_pysph_")
    old_cwd = os.getcwd()
    try:
        os.chdir(tmp)
        # PySPH/compyle keep generated code under ~/.pysph and ~/.compyle:
        # point HOME at the temp dir (or a cache dir the caller keeps).
        os.environ["HOME"] = cache_dir or tmp

        from compyle.config import get_config
        from pysph.base.kernels import WendlandQuintic
        from pysph.solver.application import Application
        from pysph.sph.integrator import EPECIntegrator, PECIntegrator
        from pysph.sph.scheme import WCSPHScheme
        from cyarray.api import UIntArray
        import numpy as np

        integrator_cls = {"pec": PECIntegrator, "epec": EPECIntegrator}[integrator]
        marks: list[float] = []
        target = steps + 1

        class DamBreak(Application):
            def create_particles(self):
                return list(make_particles(dx, hdx, layers))

            def create_scheme(self):
                return WCSPHScheme(
                    ["fluid"], ["boundary"], dim=3, rho0=RHO0, c0=C0,
                    h0=hdx * dx, hdx=hdx, gy=-G, alpha=alpha, beta=0.0,
                    gamma=GAMMA, hg_correction=True, tensile_correction=False)

            def configure_scheme(self):
                self.scheme.configure_solver(
                    kernel=WendlandQuintic(dim=3), integrator_cls=integrator_cls,
                    dt=dt, tf=1.0e6, adaptive_timestep=False, pfreq=10**9)

            def post_step(self, solver):
                marks.append(time.perf_counter())

        app = DamBreak(fname="dam_break_bench", output_dir=os.path.join(tmp, "out"))
        app.setup([
            "--openmp", "--disable-output", "-q", "--max-steps", str(target),
            "-d", os.path.join(tmp, "out"),
        ])
        if not get_config().use_openmp:
            raise RuntimeError("OpenMP was not enabled")
        app.solve()
        if len(marks) < target:
            raise RuntimeError(f"only {len(marks)} of {target} steps ran")
        wall = marks[target - 1] - marks[0]

        fluid, boundary = app.particles
        front_x = float(fluid.x.max())
        ok = bool(np.all(np.isfinite(fluid.x)) and np.all(np.isfinite(fluid.y)))
        n_fluid = int(fluid.get_number_of_particles())
        n_bound = int(boundary.get_number_of_particles())
        # Mean neighbours per fluid particle (end state, within 2h, self
        # excluded), with PySPH's own neighbour search.
        nnps = app.nnps
        nnps.update()
        nbrs = UIntArray()
        counts = [0, 0]
        for src in (0, 1):
            for d in range(n_fluid):
                nnps.get_nearest_particles(src, 0, d, nbrs)
                counts[src] += nbrs.length
        counts[0] -= n_fluid  # self
        actual_dt = float(app.solver.dt)
        if abs(actual_dt - dt) > 1e-12 * dt:
            raise RuntimeError(f"solver dt {actual_dt} != requested {dt}")
    finally:
        os.chdir(old_cwd)
        shutil.rmtree(tmp, ignore_errors=True)

    return {
        "code": "pysph",
        "method": "wcsph",
        "particles": n_fluid,
        "boundary_particles": n_bound,
        "neighbours": (counts[0] + counts[1]) / max(n_fluid, 1),
        "dt": actual_dt,
        "steps": steps,
        "threads": threads,
        "wall_s": wall,
        "particle_steps_per_s": n_fluid * steps / wall,
        # extra details (not required by sph bench)
        "neighbours_fluid": counts[0] / max(n_fluid, 1),
        "neighbours_boundary": counts[1] / max(n_fluid, 1),
        "support_radius": 2.0 * hdx * dx,
        "kernel": "Wendland quintic, support 2h",
        "hdx": hdx,
        "boundary_layers": layers,
        "integrator": integrator,
        "front_x_end": front_x,
        "finite": ok,
        "alpha": alpha,
        "version": _version(),
    }


def _version() -> str:
    try:
        from importlib.metadata import version
        return version("pysph")
    except Exception:  # pragma: no cover
        return "unknown"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--dx", type=float, default=0.0125)
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--threads", type=int, default=int(os.environ.get("OMP_NUM_THREADS", "1")))
    p.add_argument("--method", choices=["wcsph"], default="wcsph")
    p.add_argument("--hdx", type=float, default=1.15,
                   help="h/dx; support radius is 2h (default 2.3 dx)")
    p.add_argument("--boundary-layers", type=int, default=1,
                   help="layers of boundary particles (PySPH's dam_break_3d uses 1)")
    p.add_argument("--dt", type=float, default=None,
                   help="fixed time step (default 1e-4 * dx / 0.0125)")
    p.add_argument("--integrator", choices=["pec", "epec"], default="pec",
                   help="pec: one force evaluation per step (default); "
                        "epec: two (as PySPH's dam_break_3d example)")
    p.add_argument("--alpha", type=float, default=0.25,
                   help="artificial viscosity alpha")
    p.add_argument("--cache-dir", default=None,
                   help="keep PySPH's compiled code here (default: temp dir)")
    a = p.parse_args(argv)
    os.environ["OMP_NUM_THREADS"] = str(a.threads)
    out_fd = os.dup(1)
    os.dup2(2, 1)  # keep stdout for the JSON line only
    old_stdout = sys.stdout
    sys.stdout = sys.stderr
    try:
        res = run(a.dx, a.steps, a.threads, a.hdx, a.boundary_layers, a.dt,
                  a.integrator, a.alpha, a.cache_dir)
    except BaseException:
        import traceback
        os.write(2, traceback.format_exc().encode())
        raise SystemExit(1)
    finally:
        sys.stdout = old_stdout
        sys.stderr.flush()
        os.dup2(out_fd, 1)
        os.close(out_fd)
    sys.stdout.write(json.dumps(res) + "\n")
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
