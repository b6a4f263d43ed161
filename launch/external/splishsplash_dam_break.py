"""3D dam break in SPlisHSPlasH (``pysplishsplash``), timed for ``sph bench``.

Standalone script: run it with the interpreter of the venv that has
``pysplishsplash`` installed (see ``scripts/setup_bench.sh``) and with
``LD_PRELOAD=/lib/x86_64-linux-gnu/libGLdispatch.so.0`` (the wheel links GL
libraries that otherwise fail to load on a headless machine).  Prints ONE line
of JSON to stdout; everything SPlisHSPlasH logs goes to stderr / the temp dir.

The scene mirrors our ``dam_break.toml``: tank [0,1.6]x[0,0.6]x[0,0.6] (y up),
water column [0,0.4]x[0,0.4]x[0,0.6] sampled on a cubic lattice at
(i+0.5)*dx, particle radius dx/2, rest density 1000, gravity -9.81 in y,
fixed time step (CFL off).  Only the stepping loop is timed: the clock
starts after the first (warm-up) step, which follows scene set-up, boundary
sampling and the first neighbour search, and stops after ``steps`` more steps.
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

# Scene constants (same as our dam_break.toml).
TANK = (1.6, 0.6, 0.6)
COLUMN = (0.4, 0.4, 0.6)
RHO0 = 1000.0
G = 9.81
GAMMA = 7.0
C0 = 10.0 * math.sqrt(2.0 * G * COLUMN[1])  # ~28 m/s

# Only Akinci2012 (boundary particles) is validated here; the volume-map
# method (Bender2019) blew up with this scene in a quick test.
BOUNDARY_METHODS = {"akinci2012": 0}
SIM_METHODS = {"wcsph": 0, "dfsph": 4}


def _box_obj(path: str) -> None:
    """Unit cube centred at the origin, as a closed triangle mesh (OBJ).

    SPlisHSPlasH scales/translates it into the tank; with ``mapInvert`` the
    fluid lives inside.  Face winding is outward (as for a solid box).
    """
    v = [(x, y, z) for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)]
    idx = {p: i + 1 for i, p in enumerate(v)}

    def q(a, b, c, d):
        return [(idx[a], idx[b], idx[c]), (idx[a], idx[c], idx[d])]

    lo, hi = -0.5, 0.5
    faces = []
    faces += q((lo, lo, lo), (lo, lo, hi), (lo, hi, hi), (lo, hi, lo))  # -x
    faces += q((hi, lo, lo), (hi, hi, lo), (hi, hi, hi), (hi, lo, hi))  # +x
    faces += q((lo, lo, lo), (hi, lo, lo), (hi, lo, hi), (lo, lo, hi))  # -y
    faces += q((lo, hi, lo), (lo, hi, hi), (hi, hi, hi), (hi, hi, lo))  # +y
    faces += q((lo, lo, lo), (lo, hi, lo), (hi, hi, lo), (hi, lo, lo))  # -z
    faces += q((lo, lo, hi), (hi, lo, hi), (hi, hi, hi), (lo, hi, hi))  # +z
    with open(path, "w") as f:
        for p in v:
            f.write("v %g %g %g\n" % p)
        for t in faces:
            f.write("f %d %d %d\n" % t)


def make_scene(tmp: str, dx: float, dt: float, method: str, boundary: str,
               viscosity: float, wall_gap: float = 0.75, max_dt: float | None = None) -> str:
    """The scene file; with ``max_dt`` the step is SPlisHSPlasH's CFL step (its default factor 0.5)
    up to ``max_dt``, starting at ``dt``; without, ``dt`` is fixed."""
    mesh = os.path.join(tmp, "tank_box.obj")
    _box_obj(mesh)
    r = 0.5 * dx
    # FluidBlock (denseMode 0) places particles at start + diam*(k+1),
    # k = 0..round((end-start)/diam)-2.  Choosing start = -dx/2 and
    # end = (n+0.5)*dx gives exactly n particles at (k+0.5)*dx.
    n = [int(round(L / dx)) for L in COLUMN]
    start = [-0.5 * dx] * 3
    end = [(ni + 0.5) * dx for ni in n]
    # Volume/density-map resolution: ~ one cell per 2 particle diameters.
    map_res = [max(8, int(math.ceil(L / (2.0 * dx)))) for L in TANK]
    stiffness = RHO0 * C0 * C0 / GAMMA  # Tait B = rho0 c^2 / gamma
    config = {
        "particleRadius": r,
        "simulationMethod": SIM_METHODS[method],
        "gravitation": [0.0, -G, 0.0],
        "timeStepSize": dt,
        "cflMethod": 0 if max_dt is None else 1,  # fixed time step, or the CFL step
        "cflFactor": 1.0 if max_dt is None else 0.5,
        "cflMaxTimeStepSize": dt if max_dt is None else max_dt,
        "numberOfStepsPerRenderUpdate": 1,
        "boundaryHandlingMethod": BOUNDARY_METHODS[boundary],
        "enablePartioExport": False,
        "enableVTKExport": False,
        "enableRigidBodyExport": False,
        "enableStateExport": False,
        # Time-step parameters live in a section named after the method.
        "WCSPH": {"stiffness": stiffness, "exponent": GAMMA},
        "DFSPH": {
            "minIterations": 2,
            "maxIterations": 100,
            "maxError": 0.05,
            "maxIterationsV": 100,
            "maxErrorV": 0.1,
            "enableDivergenceSolver": True,
        },
    }
    material = {"id": "Fluid", "density0": RHO0}
    if viscosity > 0.0:
        material["viscosityMethod"] = 1  # "Standard" viscosity
        material["Standard viscosity"] = {"viscosity": viscosity}
    else:
        material["viscosityMethod"] = 0
    scene = {
        "Configuration": config,
        "Materials": [material],
        "RigidBodies": [{
            "geometryFile": mesh,
            "translation": [0.5 * L for L in TANK],
            "rotationAxis": [1, 0, 0],
            "rotationAngle": 0,
            # Boundary surface wall_gap*dx outside the tank.  With the
            # surface at x=0 (fluid at r from the samples) Akinci2012
            # over-counts density near the walls (1.8x rho0 at edges) and
            # both methods blow up; at 0.5 dx WCSPH is fine but DFSPH
            # explodes on the 10% initial overshoot; 0.75 dx runs stable.
            "scale": [L + 2.0 * wall_gap * dx for L in TANK],
            "color": [0.1, 0.4, 0.6, 1.0],
            "isDynamic": False,
            "isWall": True,
            "mapInvert": True,
            "mapThickness": 0.0,
            "mapResolution": map_res,
        }],
        "FluidBlocks": [{
            "id": "Fluid",
            "denseMode": 0,
            "start": start,
            "end": end,
            "translation": [0.0, 0.0, 0.0],
            "scale": [1, 1, 1],
        }],
    }
    path = os.path.join(tmp, "dam_break.json")
    with open(path, "w") as f:
        json.dump(scene, f, indent=1)
    return path


def run(dx: float, steps: int, threads: int, method: str, boundary: str,
        dt: float | None, viscosity: float, wall_gap: float, until: float | None = None,
        max_dt: float = 0.005) -> dict:
    """``steps`` fixed steps; or, with ``until``, the CFL step (up to ``max_dt``) from rest to
    ``until`` simulated seconds, timed from the end of the first step."""
    if dt is None:
        dt = 1.0e-4 * dx / 0.0125  # same CFL number at every resolution
    tmp = tempfile.mkdtemp(prefix="sph_bench_splishsplash_")
    old_cwd = os.getcwd()
    try:
        os.chdir(tmp)  # anything written relative to cwd lands here too
        scene_file = make_scene(tmp, dx, dt, method, boundary, viscosity, wall_gap,
                                None if until is None else max_dt)

        import pysplishsplash as sph  # noqa: WPS433 (import after env set-up)

        base = sph.Exec.SimulatorBase()
        base.init(sceneFile=scene_file, useGui=False, useCache=False,
                  outputDir=os.path.join(tmp, "output"), initialPause=False,
                  stopAt=1.0e6 if until is None else until)
        base.initSimulation()

        sim = sph.Simulation.getCurrent()
        tm = sph.TimeManager.getCurrent()
        marks: list[float] = []
        times: list[float] = []
        iterations: list[tuple[int, int]] = []  # DFSPH: (density, divergence) iterations of each step
        target = steps + 1  # 1 warm-up step + timed steps
        step_method = sim.getTimeStep() if method == "dfsph" else None

        def on_step():
            marks.append(time.perf_counter())
            times.append(float(tm.getTime()))
            if step_method is not None:
                iterations.append((step_method.getValueInt(sph.TimeStepDFSPH.SOLVER_ITERATIONS),
                                   step_method.getValueInt(sph.TimeStepDFSPH.SOLVER_ITERATIONS_V)))
            if until is None and len(marks) >= target:
                # stopAt > 0 and < current time ends runSimulation's loop.
                base.setValueFloat(base.STOP_AT, 1.0e-12)

        base.setTimeStepCB(on_step)
        base.runSimulation()  # deferred init, then steps until STOP_AT
        if until is not None:
            target = len(marks)
            if target < 2 or times[-1] < 0.99 * until:
                raise RuntimeError(f"stopped at t = {times[-1] if times else 0.0:g} s of {until:g} s")
            steps = target - 1
        if len(marks) < target:
            raise RuntimeError(f"only {len(marks)} of {target} steps ran")
        wall = marks[target - 1] - marks[0]
        simulated = times[target - 1] - times[0]
        solves = {}
        if iterations:  # the timed steps' (after the first)
            timed = iterations[1:target]
            for k, name in enumerate(("density", "divergence")):
                solves[name] = {"iterations_per_step": sum(it[k] for it in timed) / max(len(timed), 1),
                                "max": max((it[k] for it in timed), default=0)}

        model = sim.getFluidModel(0)
        n_fluid = int(model.numActiveParticles())
        n_boundary = 0
        if boundary == "akinci2012":
            for b in range(sim.numberOfBoundaryModels()):
                n_boundary += int(sim.getBoundaryModel(b).numberOfParticles())
        # Neighbour counts from the last neighbour search (end state).
        n_point_sets = sim.numberOfPointSets()
        nb_fluid = 0
        nb_bound = 0
        for i in range(n_fluid):
            nb_fluid += sim.numberOfNeighbors(0, 0, i)
            for ps in range(1, n_point_sets):
                nb_bound += sim.numberOfNeighbors(0, ps, i)
        actual_dt = float(tm.getTimeStepSize())
        support = float(sim.getSupportRadius())
        base.cleanup()
    finally:
        os.chdir(old_cwd)
        shutil.rmtree(tmp, ignore_errors=True)

    return {
        "code": "splishsplash",
        "method": method,
        "particles": n_fluid,
        "boundary_particles": n_boundary,
        "neighbours": (nb_fluid + nb_bound) / max(n_fluid, 1),
        "dt": actual_dt,
        "steps": steps,
        "threads": threads,
        "wall_s": wall,
        "particle_steps_per_s": n_fluid * steps / wall,
        "simulated_s": simulated,
        "mean_dt": simulated / max(steps, 1),
        "sim_s_per_wall_s": simulated / wall,
        "until_s": until,
        "solves": solves,
        # extra details (not required by sph bench)
        "neighbours_fluid": nb_fluid / max(n_fluid, 1),
        "neighbours_boundary": nb_bound / max(n_fluid, 1),
        "boundary_method": boundary,
        "support_radius": support,
        "kernel": "cubic spline (SPlisHSPlasH default), support 4r = 2dx",
        "viscosity": viscosity,
        "wall_gap_dx": wall_gap,
        "version": _version(),
    }


def _version() -> str:
    try:
        from importlib.metadata import version
        return version("pysplishsplash")
    except Exception:  # pragma: no cover
        return "unknown"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--dx", type=float, default=0.0125)
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--threads", type=int, default=int(os.environ.get("OMP_NUM_THREADS", "1")))
    p.add_argument("--method", choices=sorted(SIM_METHODS), default="wcsph")
    p.add_argument("--boundary", choices=sorted(BOUNDARY_METHODS), default="akinci2012",
                   help="boundary handling; akinci2012 = boundary particles (default)")
    p.add_argument("--dt", type=float, default=None,
                   help="fixed time step (default 1e-4 * dx / 0.0125)")
    p.add_argument("--viscosity", type=float, default=0.01,
                   help="standard viscosity coefficient; 0 disables viscosity")
    p.add_argument("--until", type=float, default=None,
                   help="instead of --steps: the CFL step from rest to this simulated time in s")
    p.add_argument("--max-dt", type=float, default=0.005,
                   help="--until: the largest CFL step in s (SPlisHSPlasH's default 0.005)")
    p.add_argument("--wall-gap", type=float, default=0.75,
                   help="boundary surface distance outside the tank, in dx")
    a = p.parse_args(argv)
    # OpenMP reads OMP_NUM_THREADS when its runtime starts; set it before the
    # extension module is imported (the runner also sets it).
    os.environ["OMP_NUM_THREADS"] = str(a.threads)
    # Keep stdout for the JSON line only: send the library's console output
    # (C++ std::cout) to stderr by swapping file descriptors.
    out_fd = os.dup(1)
    os.dup2(2, 1)
    try:
        res = run(a.dx, a.steps, a.threads, a.method, a.boundary, a.dt, a.viscosity,
                  a.wall_gap, a.until, a.max_dt)
    finally:
        sys.stdout.flush()
        os.dup2(out_fd, 1)
        os.close(out_fd)
    sys.stdout.write(json.dumps(res) + "\n")
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
