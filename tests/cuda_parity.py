"""CPU vs CUDA parity cases, run as a script (tests/test_cuda.py starts it in a subprocess, because
NUMBA_ENABLE_CUDASIM must be set before numba is first imported; on a GPU it runs as is).

    python tests/cuda_parity.py [CASE ...]      prints one JSON object: {case: {metric: value}}
                                                (and on stderr each case's metrics and seconds)

Errors are scaled by each field's natural size, so that a near-zero field (pressure at rest) does
not turn round-off into a large "relative" error: x by the domain extent, v by max |v| (and 1 m/s),
rho by rho0, p by rho0 c0^2 (the Tait stiffness times 7), a by max |a|.
"""
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from nodes.cluster import InProcessCluster  # noqa: E402
from sphcore.scene import load_scene  # noqa: E402
from sphcore.solver import Simulation  # noqa: E402


def scene(name, *overrides):
    # no skin on either side: the device builds its lists every step (scene.list_skin), and the CPU's
    # reused lists would sum in another order; with a skin the CPU keeps its own guarantees
    # (tests/test_neighbour_skin.py)
    return load_scene(ROOT / "configs" / name, ["run.neighbour_skin=0", *overrides])


# The tiny scene at a coarser spacing: 117 particles instead of 498, the same walls, corners, drop and
# 56 neighbours in the bulk. Every thread of the simulator is Python, and a particle near the box's
# corners sums its virtual points one by one, so the cost goes with the particles: tiny_f64 took 160 s
# on one core of the development machine at 498 particles (2026-12-04).
def tiny(*overrides):
    return scene("tiny.toml", "particles.spacing=0.02", *overrides)


# channel_2d.toml shortened from 6 to 2 cm (200 particles at 1 mm): the inlet and outlet zones unchanged
SHORT_CHANNEL = ("fluid.blocks[0].max=[2e-2, 1e-2]", "domain.bounds_max=[2e-2, 1e-2]", "outlets[0].min=[1.7e-2, 0]",
                 "outlets[0].max=[2e-2, 1e-2]")


# wave_maker_2d.toml shortened from 2 to 0.5 m (125 particles at 2 cm): the damping zone over its far 0.3 m
SHORT_FLUME = ("particles.spacing=0.02", "fluid.blocks[0].max=[0.5, 0.1]", "domain.bounds_max=[0.5, 0.25]",
               "domain.planes[1].point=[0.5, 0.0]", "damping_zones[0].min=[0.2, 0.0]",
               "damping_zones[0].max=[0.5, 0.25]")


def _scales(sim):
    s = sim.state
    n = s.n_owned
    extent = float(np.max(sim.walls.hi - sim.walls.lo))
    return {"x": extent, "v": max(float(np.max(np.abs(s.v[:n]))), 1.0), "rho": float(sim.prm.rho0),
            "p": float(sim.prm.rho0) * float(sim.prm.c0) ** 2, "a": max(float(np.max(np.abs(s.a[:n]))), 1.0)}


def compare(cpu, gpu, fields=("x", "v", "rho", "p", "a")) -> dict:
    """Max scaled difference per field over owned rows, matched by particle id."""
    a, b = cpu.state, gpu.state
    na, nb = a.n_owned, b.n_owned
    oa = np.argsort(a.id[:na], kind="stable")
    ob = np.argsort(b.id[:nb], kind="stable")
    if na != nb or not np.array_equal(a.id[:na][oa], b.id[:nb][ob]):
        return {"same_particles": False}
    scale = _scales(cpu)
    out = {"same_particles": True}
    for f in fields:
        x = getattr(a, f)[:na][oa].astype(np.float64)
        y = getattr(b, f)[:nb][ob].astype(np.float64)
        out[f] = float(np.max(np.abs(x - y))) / scale[f] if len(x) else 0.0
    return out


def copy_state(src, dst):
    """dst continues from src's exact particles (so a stage is compared on identical input)."""
    from sphcore.state import ParticleState
    s = src.state
    n = s.n_owned
    dst.state = ParticleState.create(s.id[:n].copy(), s.x[:n].copy(), s.v[:n].copy(), s.m[:n].copy(), dst.dtype,
                                     extra={k: a[:n].copy() for k, a in s.extra.items()})
    dst.t, dst.step_index, dst.dt_prev = src.t, src.step_index, src.dt_prev


def stages_case(sc, precision, warm_steps=5, steps=3) -> dict:
    """One refresh (grid, density, forces) on identical input, stage by stage; then whole steps."""
    cpu = Simulation(sc, precision, "cpu")
    for _ in range(warm_steps):  # irregular positions, moving particles, nonzero pressure
        cpu.step()
    gpu = Simulation(sc, precision, "cuda")
    copy_state(cpu, gpu)
    cpu.refresh()
    gpu.refresh()
    out = {}
    a, b = cpu.state, gpu.state
    n = a.n_owned
    out["same_order"] = bool(np.array_equal(a.id, b.id))
    counts_a, counts_b = cpu.grid.counts[:n], gpu.grid.counts
    out["same_counts"] = bool(np.array_equal(counts_a, counts_b))
    nbr_b = gpu.grid.d_nbr.copy_to_host()
    out["same_neighbour_lists"] = bool(out["same_counts"] and all(
        np.array_equal(cpu.grid.nbr[i, :counts_a[i]], nbr_b[i, :counts_a[i]]) for i in range(n)))
    out["stage"] = compare(cpu, gpu, ("rho", "p", "a"))
    for _ in range(steps):
        cpu.step()
        gpu.step()
    out["steps"] = compare(cpu, gpu)
    out["dt_rel"] = abs(cpu.dt - gpu.dt) / cpu.dt
    out["leaks"] = [cpu.leaks, gpu.leaks]
    for b_cpu, b_gpu in zip(cpu.model.walls.bodies, gpu.model.walls.bodies):  # floating bodies: moved alike
        out["body_x"] = max(out.get("body_x", 0.0), float(np.max(np.abs(b_cpu.x - b_gpu.x))) / _scales(cpu)["x"])
    return out


def steps_case(sc, precision, steps) -> dict:
    cpu = Simulation(sc, precision, "cpu")
    gpu = Simulation(sc, precision, "cuda")
    for _ in range(steps):
        cpu.step()
        gpu.step()
    cpu.refresh()
    gpu.refresh()
    out = compare(cpu, gpu)
    out["dt_rel"] = abs(cpu.dt - gpu.dt) / cpu.dt
    out["leaks"] = [cpu.leaks, gpu.leaks]
    for b_cpu, b_gpu in zip(cpu.model.walls.bodies, gpu.model.walls.bodies):  # floating bodies: moved alike
        out["body_x"] = max(out.get("body_x", 0.0), float(np.max(np.abs(b_cpu.x - b_gpu.x))) / _scales(cpu)["x"])
        out["body_R"] = max(out.get("body_R", 0.0), float(np.max(np.abs(b_cpu.R - b_gpu.R))))  # turned alike
        out["body_turned"] = float(np.max(np.abs(b_cpu.R - np.eye(3))))
    return out


def peers_case(sc, precision, steps) -> dict:
    """Two in-process peers on the CUDA backend (halo exchanges through the host mirror) against one
    CPU process."""
    cpu = Simulation(sc, precision, "cpu")
    cluster = InProcessCluster(sc, 2, precision, backend="cuda")
    for _ in range(steps):
        cpu.step()
        cluster.step()
    ref = cpu.final_arrays()
    got = cluster.final_arrays()
    if not np.array_equal(ref["id"], got["id"]):
        return {"same_particles": False}
    scale = _scales(cpu)
    out = {"same_particles": True, "ghosts": int(sum(h.ghosts_received for h in cluster.halos))}
    for f in ("x", "v", "rho"):
        out[f] = float(np.max(np.abs(ref[f].astype(np.float64) - got[f]))) / scale[f]
    return out


def open_case(sc, precision, steps) -> dict:
    """Inlets and outlets: the CPU runs to just before the inlet's next layer, the device continues
    from its particles, and both step across that layer's creation and the outlet's removals."""
    cpu = Simulation(sc, precision, "cpu")
    lattice = cpu.open.inlets[0]
    next_layer = (lattice.layers(0.0) - lattice.K0 + 0.5) * lattice.dx / lattice.U  # the first new layer's time
    while cpu.t + 3.0 * max(cpu.dt, 1e-12) < next_layer:
        cpu.step()
    gpu = Simulation(sc, precision, "cuda")
    copy_state(cpu, gpu)
    gpu.n_particles, gpu.dt = cpu.n_particles, cpu.dt
    gpu.open.inflow, gpu.open.outflow = cpu.open.inflow, cpu.open.outflow
    before = cpu.n_particles, cpu.open.inflow, cpu.open.outflow
    for _ in range(steps):
        cpu.step()
        gpu.step()
    cpu.refresh()
    gpu.refresh()
    out = compare(cpu, gpu)
    out["counts"] = [before, (cpu.n_particles, cpu.open.inflow, cpu.open.outflow),
                     (gpu.n_particles, gpu.open.inflow, gpu.open.outflow)]
    return out


CASES = {
    "tiny_f64": lambda: stages_case(tiny(), "f64"),
    "tiny_f32": lambda: steps_case(tiny(), "f32", 3),
    "terms_f64": lambda: steps_case(tiny("terms.xsph=0.3", "terms.surface_tension=0.05",
                                          "terms.vorticity_confinement=0.01", "terms.shifting=1.0", "time.integrator='leapfrog'",
                                          "sph.viscosity='morris'", "sph.nu=1e-4", "sph.kernel='cubic_spline'"),
                                    "f64", 2),
    "periodic_f64": lambda: steps_case(scene("taylor_green_2d.toml", "particles.spacing=0.0833333333"), "f64", 2),
    "obstacle_f64": lambda: steps_case(scene("obstacle.toml", "particles.spacing=0.05", "sph.eos='linear'",
                                             "sph.viscosity='muller'", "sph.nu=1e-4", "sph.kernel='muller'"),
                                       "f64", 2),
    "peers_f64": lambda: peers_case(tiny("sph.viscosity_switch='balsara'"), "f64", 2),  # f with exchange 2
    # with Balsara's switch on the artificial viscosity (its pass, and its factor in the forces)
    "continuity_f64": lambda: steps_case(tiny("sph.density='continuity'", "sph.viscosity_switch='balsara'"), "f64", 3),
    "dfsph_f64": lambda: steps_case(tiny("sph.solver='dfsph'", "time.dt=0.002"), "f64", 3),
    "dfsph_peers_f64": lambda: peers_case(tiny("sph.solver='dfsph'", "time.dt=0.002"), "f64", 2),
    # the same in 2D (200 particles, ~20 neighbours each): 74 s in the simulator on one core of the
    # development machine against 242 s for the 3D case (start-up included)
    "dfsph_peers_2d_f64": lambda: peers_case(scene("dam_break_2d.toml", "particles.spacing=0.03", "sph.solver='dfsph'",
                                                   "time.dt=0.002"), "f64", 3),
    # the cell walk (run.neighbours = "walk"): every neighbour pass walks the cells on the device
    "walk_terms_f64": lambda: steps_case(tiny("run.neighbours='walk'", "terms.xsph=0.3",
                                               "terms.surface_tension=0.05", "terms.vorticity_confinement=0.01",
                                               "sph.density='continuity'", "sph.viscosity_switch='balsara'"), "f64", 2),
    # moving walls (motion.py): a sliding plate with the Morris no-slip wall, oscillating across the
    # channel so that the wall's velocity and acceleration both enter (viscous drag, pressure, collision),
    # and the turbulent wall friction's law of the wall on the slip relative to each plate
    "moving_walls_f64": lambda: steps_case(scene("couette_2d.toml", "particles.spacing=5e-5",
                                                 "domain.planes[1].amplitude=[0, 2e-5]",
                                                 "domain.planes[1].frequency=10", "terms.wall_friction=1e-6"),
                                           "f64", 3),
    # a floating body: its force and torque, the reaction to its wall's terms, reduced on the device
    "floating_f64": lambda: steps_case(scene("floating_box_2d.toml", "particles.spacing=0.06",
                                             "forces.ramp_time=0.001", "obstacles[0].rotation=[0, 0, 10]",
                                             "obstacles[0].free_rotation=[false, false, true]"), "f64", 5),
    # the difference form of the pressure gradient (physics/pressure.py): C_i, the zeroth-order part, the
    # surface layer's share and the gradient moment B_i (the walls' in it), about a floating cylinder
    # whose force is the traction's (physics/traction.py: the moments of the state the device leaves)
    "difference_f64": lambda: steps_case(scene("settling_cylinder_2d.toml", "particles.spacing=2e-3",
                                               "sph.pressure_gradient='difference'", "terms.shifting=2.0",
                                               "sph.body_force='traction'", "forces.ramp_time=0.001"), "f64", 3),
    # a turning wall (motion.py): the inner cylinder's velocity Omega x (r - P) at each wall point
    "rotating_f64": lambda: steps_case(scene("circular_couette_2d.toml", "particles.spacing=2e-4"), "f64", 3),
    # inlets and outlets (open_boundary.py): a layer enters, rows leave, on the device as on the CPU
    "open_f64": lambda: open_case(scene("channel_2d.toml", "particles.spacing=1e-3", *SHORT_CHANNEL), "f64", 6),
    # a damping zone (physics/damping.py) beside a moving piston: a -= k(x) v
    "damping_f64": lambda: steps_case(scene("wave_maker_2d.toml", *SHORT_FLUME), "f64", 3),
    "walk_dfsph_peers_f64": lambda: peers_case(tiny("run.neighbours='walk'", "sph.solver='dfsph'",
                                                     "time.dt=0.002"), "f64", 2),
}


def main(names):
    results = {}
    for name in names or CASES:
        started = time.perf_counter()
        results[name] = CASES[name]()
        print(f"{name} ({time.perf_counter() - started:.1f} s): {results[name]}", file=sys.stderr, flush=True)
    print(json.dumps(results))


if __name__ == "__main__":
    os.chdir(ROOT)
    if os.environ.get("NUMBA_ENABLE_CUDASIM") == "1":
        # numba's simulator runs every thread of a block as a Python thread, and its block manager polls
        # them in a loop that holds the GIL: each handoff waited out Python's switch interval (5 ms),
        # which made the block reductions' syncthreads most of a case's time. At 0.3 ms the 2D DFSPH
        # over two peers took 35 s instead of 136 s and open_f64 13.5 s instead of 34.4 s, the same
        # differences (2026-12-07). The simulated arithmetic does not depend on the thread schedule once
        # a block's threads share one shared array: the faster handoffs exposed the simulator's racy
        # allocation (CI: a garbage statistic, a NaN stop), which backends/cuda.locked_shared_arrays closes.
        sys.setswitchinterval(3e-4)
    main(sys.argv[1:])
