"""``sph bench``: particle-steps/s of the 3D dam break against N, precision and threads.

Each case sets the spacing so that the dam break's water column holds about N particles, runs one
step to compile (or load numba's cache), then times ``--steps`` steps of the stepping loop only.
With ``--external`` the same scene (same tank, column, spacing and step count) runs in PySPH and
SPlisHSPlasH in subprocesses (``launch/external``), so all figures come from one run on one
machine, and ratios are printed side by side. With ``--peers 1 2 ...`` each case also runs as
``sph run --peers P`` (P processes over Zenoh on this machine, ``--threads`` numba threads each),
timed by the run's own summary, and the multi-peer speed-up over one peer is printed. Last, per
backend, about how many particles fit in one 16.67 ms step (``frame_budget``).
"""
from __future__ import annotations

import json
import logging
import platform
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

import numba
import numpy as np

from sphcore.children import module_command, module_env
from sphcore.output import write_json
from sphcore.scene import load_scene, shear_viscosity
from sphcore.solver import Simulation

log = logging.getLogger("sph.bench")
DEFAULT_SCENE = Path(__file__).resolve().parent.parent / "configs" / "dam_break.toml"


def _fluid_volume(scene) -> float:
    """The volume (area in 2D) of the scene's fluid blocks (m^dim)."""
    volume = 0.0
    for b in scene.fluid.blocks:
        if b.shape == "box":
            volume += float(np.prod([b.max[d] - b.min[d] for d in range(scene.dim)]))
        else:
            volume += (np.pi * b.radius**2) if scene.dim == 2 else (4.0 / 3.0 * np.pi * b.radius**3)
    return volume


def spacing_for(scene_path: Path, target: int) -> float:
    """Spacing that gives about ``target`` particles (volume of the fluid blocks / dx^dim)."""
    scene = load_scene(scene_path)
    return float((_fluid_volume(scene) / target) ** (1.0 / scene.dim))


def fixed_dt(scene_path: Path, dx: float) -> float:
    """The benchmark's fixed step: 1e-4 s, or half the acoustic limit h / c0 at spacing ``dx`` when
    that is shorter (from about 1 M particles up), so that fine cases stay stable as the column falls."""
    sph = load_scene(scene_path).sph
    h = 0.5 * sph.support * dx
    return min(1e-4, 0.5 * h / sph.sound_speed)


def _fixed(scene_path: Path, dx: float) -> list[str]:
    """The case's overrides: its spacing and fixed step, and no particle limit below the size asked
    for (the scene's max_particles guards against a mistyped spacing; here the size is the point)."""
    scene = load_scene(scene_path)
    limit = max(scene.particles.max_particles, int(2 * _fluid_volume(scene) / dx**scene.dim))
    return [f"particles.spacing={dx!r}", "time.mode='fixed'", f"time.dt={fixed_dt(scene_path, dx)!r}",
            f"particles.max_particles={min(limit, 10**10)}"]


def _memory_kb(field: str) -> int | None:
    """VmRSS (resident now) or VmHWM (peak since the last reset) of this process in kB (Linux)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1])
    except OSError:
        pass
    return None


def _reset_peak_memory():
    """Reset VmHWM to the current RSS (Linux: writing 5 to /proc/self/clear_refs)."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass


def _device_used() -> int | None:
    """Bytes in use on the GPU, after freeing what earlier cases left for numba to free later (else
    a case would count the previous case's arrays being freed as negative use)."""
    import gc

    from numba import cuda
    try:
        gc.collect()
        context = cuda.current_context()
        context.deallocations.clear()
        free, total = context.get_memory_info()
        return int(total - free)
    except Exception:  # noqa: BLE001 - no device (simulator) or a driver without the query
        return None


def bench_case(scene_path: Path, dx: float, precision: str, threads: int, steps: int, backend: str = "cpu",
               neighbours: str = "lists", skin: float = -1.0, after: int = 0) -> dict:
    """One timed case. Memory per particle: the host's peak RSS during the timed steps over its RSS
    before set-up (so it holds the state, scratch and grid; compiled code too on a cold cache), and on
    a GPU the device memory in use after the steps over that before set-up. ``skin``:
    run.neighbour_skin; ``after``: steps run untimed first (the flow developed, not at rest)."""
    numba.set_num_threads(threads)
    scene = load_scene(scene_path, _fixed(scene_path, dx) + [f"run.neighbours={neighbours!r}",
                                                             f"run.neighbour_skin={skin!r}"], backend=backend)
    rss_before = _memory_kb("VmRSS")
    device_before = _device_used() if backend == "cuda" else None
    sim = Simulation(scene, precision, backend)
    t0 = time.perf_counter()
    sim.step()  # compile or load the cache
    first = time.perf_counter() - t0
    for k in range(after):
        sim.step()
        if (k + 1) % 500 == 0:
            print(f"  {k + 1} of {after} untimed steps (t = {sim.t:.3f} s)", file=sys.stderr, flush=True)
    builds = sim.grid.builds
    sim.timers.reset()
    _reset_peak_memory()
    t0 = time.perf_counter()
    for _ in range(steps):
        sim.step()
    wall = time.perf_counter() - t0
    timed = sim.timers.summary()
    stages = {k: v["median_s"] for k, v in timed.items()}
    # what a step spends outside its timed stages, per step (the host's own work, occasional checks)
    untimed = (wall - sum(v["total_s"] for v in timed.values())) / steps
    peak = _memory_kb("VmHWM")
    n = sim.n_particles
    host_bpp = (peak - rss_before) * 1024 / n if peak is not None and rss_before is not None else None
    device_bpp = None
    if device_before is not None:
        used = _device_used()
        device_bpp = (used - device_before) / n if used is not None else None
    return {
        "code": "sphfluid", "method": "wcsph", "backend": backend, "device": sim.device_name,
        "precision": precision, "threads": threads if backend == "cpu" else 0,
        "particles": sim.n_particles, "dx": dx, "steps": steps, "dt": sim.dt, "wall_s": wall,
        "particle_steps_per_s": sim.n_particles * steps / wall, "steps_per_s": steps / wall, "first_step_s": first,
        "neighbours": sim.neighbours_sum / max(sim.state.n_owned, 1), "neighbour_search": neighbours,
        "cells_per_support": sim.grid.reach, "neighbour_skin": sim.grid.skin, "after_steps": after,
        "list_builds": (sim.grid.builds - builds) if sim.grid.skin else steps,
        "stage_median_s": stages, "stage_total_s": {k: v["total_s"] for k, v in timed.items()},
        "untimed_s_per_step": untimed,
        "leaks": sim.leaks, "host_bytes_per_particle": host_bpp, "device_bytes_per_particle": device_bpp,
    }


# sph bench --until: each code steps the dam break from rest to T simulated seconds with its own
# adaptive step, timed from the end of its first step. DFSPH runs at SPlisHSPlasH's defaults (its
# TimeStepDFSPH: maxError 0.05 % of rho0 for the density solve, maxErrorV 0.1 % for the divergence
# solve, largest step cflMaxTimeStepSize 0.005 s), so that both codes are asked for the same accuracy.
# SPlisHSPlasH's DFSPH in `--until --external` runs twice: with the kinematic viscosity our scene's
# viscosity acts with (scene.shear_viscosity: the same fluid, so the same flow speed and CFL steps)
# and with the value its comparison used before 2026-12-07, 0.01 m^2/s (its "Standard" viscosity;
# twelve times the dam break's artificial viscosity, a slower flow in fewer, longer steps)
REFERENCE_VISCOSITY_BEFORE = 0.01
DFSPH_DENSITY_TOLERANCE = 5.0e-4
DFSPH_DIVERGENCE_TOLERANCE = 1.0e-3
UNTIL_MAX_DT = 5.0e-3


def _until_overrides(scene_path: Path, dx: float, solver: str) -> list[str]:
    """The --until case's overrides: the spacing, no particle limit below the size asked for, the
    scene's adaptive step and the solver (DFSPH at SPlisHSPlasH's tolerances and largest step)."""
    over = [kv for kv in _fixed(scene_path, dx) if kv.startswith(("particles.", ))]
    over += ["time.mode='adaptive'", f"sph.solver={solver!r}"]
    if solver == "dfsph":
        over += [f"sph.density_tolerance={DFSPH_DENSITY_TOLERANCE!r}",
                 f"sph.divergence_tolerance={DFSPH_DIVERGENCE_TOLERANCE!r}", f"time.dt={UNTIL_MAX_DT!r}"]
    return over


def bench_until_case(scene_path: Path, dx: float, precision: str, threads: int, solver: str, until: float,
                     skin: float = -1.0) -> dict:
    """Simulated seconds per wall second: ``solver`` steps the scene from rest to ``until`` seconds with
    its adaptive step; the clock starts after the first step (compile or cache load). ``skin``:
    run.neighbour_skin."""
    numba.set_num_threads(threads)
    scene = load_scene(scene_path, _until_overrides(scene_path, dx, solver) + [f"run.neighbour_skin={skin!r}"])
    sim = Simulation(scene, precision)
    t0 = time.perf_counter()
    sim.step()
    first = time.perf_counter() - t0
    t_start, step_start, builds = sim.t, sim.step_index, sim.grid.builds
    sim.timers.reset()
    t0 = time.perf_counter()
    while sim.t < until:
        sim.step(dt_cap=until - sim.t)
    wall = time.perf_counter() - t0
    steps = sim.step_index - step_start
    simulated = sim.t - t_start
    solves = {name: {"iterations_per_step": st["iterations"] / max(st["steps"], 1), "max": st["max"],
                     "unconverged_steps": st["unconverged"]} for name, st in sim.solver_stats.items()}
    return {
        "code": "sphfluid", "method": solver, "backend": "cpu", "precision": precision, "threads": threads,
        "particles": sim.n_particles, "dx": dx, "until_s": until, "simulated_s": simulated, "steps": steps,
        "mean_dt": simulated / max(steps, 1), "wall_s": wall, "sim_s_per_wall_s": simulated / wall,
        "particle_steps_per_s": sim.n_particles * steps / wall, "first_step_s": first,
        "neighbours": sim.neighbours_sum / max(sim.state.n_owned, 1), "solves": solves,
        "limits": {k: v for k, v in sim.limit_counts.items() if v}, "leaks": sim.leaks,
        "stage_total_s": {k: v["total_s"] for k, v in sim.timers.summary().items()},
        "neighbour_skin": sim.grid.skin, "list_builds": (sim.grid.builds - builds) if sim.grid.skin else steps,
    }


def _until_row(r: dict) -> str:
    solves = "".join(f" {name}={s['iterations_per_step']:.1f}it/step" for name, s in r.get("solves", {}).items())
    skin = f" skin={r['neighbour_skin']:g} ({r['list_builds']} builds)" if r.get("neighbour_skin") else ""
    viscosity = f" viscosity {r['viscosity']:.3g} m^2/s" if r["code"] != "sphfluid" and "viscosity" in r else ""
    return (f"{r['code']:>13} {r['method']:>6} {r.get('precision', 'f64'):>4} threads={r['threads']} "
            f"N={r['particles']:>8} to t={r['until_s']:g} s: {r['steps']:>6} steps, mean dt {r['mean_dt']:.2e} s, "
            f"{r['wall_s']:7.1f} s wall, {r['sim_s_per_wall_s']:.4f} simulated s per wall s{solves}{skin}{viscosity}")


def _until_cases(scene_path: Path, dx: float, args) -> list[dict]:
    """``sph bench --until T``: ours with every --solvers entry, precision and thread count; with
    --external, SPlisHSPlasH's DFSPH with its CFL step (its WCSPH takes a flow-speed step with no
    sound-speed limit, and PySPH's script runs fixed steps: neither is compared this way)."""
    out = []
    for solver in args.solvers:
        for precision in args.precisions:
            for threads in args.threads:
                for skin in args.skins:
                    r = bench_until_case(scene_path, dx, precision, threads, solver, args.until, skin)
                    out.append(r)
                    print(_until_row(r), flush=True)
    if args.external:
        from launch.external.runner import available
        if not available("splishsplash"):
            print("  splishsplash: not installed (scripts/setup_bench.sh installs it); skipped", file=sys.stderr)
            return out
        ours = shear_viscosity(load_scene(scene_path, _until_overrides(scene_path, dx, "dfsph")))
        for threads in args.threads:
            for viscosity, basis in ((ours, "matched"), (REFERENCE_VISCOSITY_BEFORE, "as before")):
                runs = _reference("splishsplash", "dfsph", dx, threads, _until_row, steps=1, timeout_s=3600,
                                  extra_args=["--until", repr(args.until), "--max-dt", repr(UNTIL_MAX_DT),
                                              "--viscosity", repr(viscosity)])
                out += [dict(r, viscosity_basis=basis) for r in runs]  # its result names its viscosity
    return out


def _print_until_ratios(results: list[dict]):
    ours = [r for r in results if r["code"] == "sphfluid" and "sim_s_per_wall_s" in r]
    theirs = [r for r in results if r["code"] != "sphfluid" and "sim_s_per_wall_s" in r]
    if not theirs:
        return
    print("\nsimulated seconds per wall second, ours / reference (same dx, end time and threads):")
    for t in theirs:
        for o in ours:
            if o["threads"] == t["threads"] and abs(o["dx"] - t["dx"]) < 1e-12:
                skin = f" skin={o['neighbour_skin']:g}" if o.get("neighbour_skin") else ""
                fluid = ""
                if "viscosity_basis" in t:  # the same fluid as ours, or the viscosity compared before
                    fluid = f", its viscosity {t['viscosity']:.3g} m^2/s ({t['viscosity_basis']})"
                print(f"  ours {o['method']} {o['precision']}{skin} vs {t['code']} {t['method']} threads={t['threads']} "
                      f"N={o['particles']}/{t['particles']}{fluid}: "
                      f"{o['sim_s_per_wall_s'] / t['sim_s_per_wall_s']:.2f}x ({o['steps']} / {t['steps']} steps)")


def run_bench(args) -> int:
    """``sph bench`` (its options checked by launch/cli.py ``check_bench``)."""
    scene_path = args.config or DEFAULT_SCENE
    device = "cpu"
    if args.backend == "cuda":
        from sphcore.backends import cuda  # loads numba-cuda: only for a CUDA run
        device = cuda.require()
    results = []
    started = datetime.now(timezone.utc)
    if args.network:
        from launch.bench_network import network_cases
        dx = spacing_for(scene_path, args.sizes[0])
        results = network_cases(scene_path, _fixed(scene_path, dx), args.steps, args.precisions[0], args.repeat)
    for target in ([] if args.network else args.sizes):
        dx = spacing_for(scene_path, target)
        if args.until is not None:
            results += _until_cases(scene_path, dx, args)
            continue
        for precision in args.precisions:
            for threads in (args.threads if args.backend == "cpu" else args.threads[:1]):
                for neighbours in args.neighbours:
                    for skin in args.skins:
                        r = bench_case(scene_path, dx, precision, threads, args.steps, args.backend, neighbours,
                                       skin, args.after)
                        results.append(r)
                        print(_row(r), flush=True)
        if args.external:
            results += _external(dx, args.steps, args.threads)
        if args.peers != [1]:
            results += _peer_cases(scene_path, dx, args)
    budget = []
    if args.until is not None:
        _print_skin_ratios(results)
        _print_until_ratios(results)
    elif not args.network:
        _print_walk_ratios(results)
        _print_skin_ratios(results)
        _print_ratios(results)
        _print_peer_ratios(results)
        budget = frame_budget(results)
        _print_frame_budget(budget)
    report = {
        "date": started.isoformat(timespec="seconds"), "command": "sph " + " ".join(sys.argv[1:]),
        "machine": {"platform": platform.platform(), "cpu": _cpu_name(), "cores": numba.config.NUMBA_NUM_THREADS,
                    "python": platform.python_version(), "numba": numba.__version__, "device": device},
        "scene": str(scene_path), "results": results, "frame_budget": budget,
    }
    if args.json:  # checked writable before the cases ran (cli._check_bench); whole or not at all
        try:
            write_json(args.json, report)
        except OSError as e:
            from nodes.driver import OutputError
            raise OutputError(f"--json {args.json}: not written ({e.strerror or e}); the results are printed "
                              "above") from None
        print(f"wrote {args.json}", file=sys.stderr)
    return 0


def _peer_cases(scene_path: Path, dx: float, args) -> list[dict]:
    """``sph run --peers P --no-viewer`` for every P and threads-per-peer T with P x T <= cores (on the
    GPU backend the peers share the device; one thread count)."""
    out = []
    cores = numba.config.NUMBA_NUM_THREADS
    for precision in args.precisions:
        for threads in (args.threads if args.backend == "cpu" else args.threads[:1]):
            for peers, skin in [(p, s) for s in args.skins for p in args.peers]:
                if peers * threads > cores:
                    continue
                with tempfile.TemporaryDirectory() as tmp:
                    cmd = module_command("launch.cli", "run", str(scene_path), "--peers", str(peers),
                                         *(["--threads", str(threads)] if args.backend == "cpu" else []),
                                         "--steps", str(args.steps + 1), "--precision", precision,
                                         "--out", tmp, "--quiet", "--no-viewer", "--backend", args.backend,
                                         "--set", "decomposition.balance_every=50", "--set",
                                         f"run.neighbour_skin={skin!r}")
                    for kv in _fixed(scene_path, dx):
                        cmd += ["--set", kv]
                    done = subprocess.run(cmd, capture_output=True, text=True, env=module_env())
                    if done.returncode != 0:
                        print(f"  {peers} peers: failed ({done.returncode}): {done.stderr[-2000:]}", file=sys.stderr)
                        continue
                    s = json.loads((Path(tmp) / "summary.json").read_text())
                r = {"code": "sphfluid", "method": "wcsph", "backend": args.backend, "precision": precision,
                     "threads": threads, "peers": peers, "particles": s["particles"], "dx": dx, "steps": s["loop"]["steps"],
                     "wall_s": s["loop"]["wall_s"], "particle_steps_per_s": s["particle_steps_per_s"],
                     "neighbours": s["neighbours"]["mean"], "bytes_sent_per_step": s["bytes_sent"] / s["steps"],
                     "bytes_over_minimum": s.get("bytes_over_minimum"), "imbalance": s.get("imbalance"),
                     "wait_s": [p["wait_s_total"] for p in s.get("per_peer", [])],
                     "neighbour_skin": s["neighbours"].get("skin", 0.0),
                     "list_builds": s["neighbours"].get("list_builds", s["steps"]),
                     "blocks": [len(c) - 1 for c in s["per_peer"][0]["cuts"]] if s.get("per_peer") else [1, 1, 1]}
                out.append(r)
                extra = ""
                if peers > 1:
                    extra = (f"  blocks {'x'.join(str(b) for b in r['blocks'])}, "
                             f"{r['bytes_sent_per_step'] / 1e3:.1f} kB/step ({r['bytes_over_minimum']:.3f}x the "
                             f"halo minimum), waiting {', '.join(f'{w:.2f}' for w in r['wait_s'])} s")
                if r["neighbour_skin"]:
                    extra += f"  skin={r['neighbour_skin']:g} ({r['list_builds']} list builds)"
                print(f"{peers:>3} peer(s) x {threads} thread(s) {precision} N={r['particles']:>8} "
                      f"{r['particle_steps_per_s']:10.3e} particle-steps/s{extra}", flush=True)
    return out


def _print_peer_ratios(results: list[dict]):
    runs = [r for r in results if "peers" in r]
    if not runs:
        return
    print("\nmulti-peer speed-up (P peers x T threads / 1 peer x T threads, same run):")
    for r in runs:
        if r["peers"] == 1:
            continue
        base = [b for b in runs if b["peers"] == 1 and b["threads"] == r["threads"]
                and b["precision"] == r["precision"] and abs(b["dx"] - r["dx"]) < 1e-12
                and b.get("neighbour_skin", 0.0) == r.get("neighbour_skin", 0.0)]
        if base:
            skin = f" skin={r['neighbour_skin']:g}" if r.get("neighbour_skin") else ""
            print(f"  {r['peers']} peers x {r['threads']} threads {r['precision']}{skin} N={r['particles']}: "
                  f"{r['particle_steps_per_s'] / base[0]['particle_steps_per_s']:.2f}x")


def _external(dx: float, steps: int, threads_list) -> list[dict]:
    from launch.external.runner import available
    out = []
    for code, methods in (("splishsplash", ("wcsph", "dfsph")), ("pysph", ("wcsph",))):
        if not available(code):
            print(f"  {code}: not installed (scripts/setup_bench.sh installs it); skipped", file=sys.stderr)
            continue
        for method in methods:
            for threads in threads_list:
                out += _reference(code, method, dx, threads, _row, steps=steps)
    return out


def _reference(code: str, method: str, dx: float, threads: int, row, **options) -> list[dict]:
    """One reference code's run (launch/external/runner.run_external ``options``), printed with
    ``row``: [its result], or [] after saying why it failed."""
    from launch.external.runner import run_external
    try:
        r = run_external(code, method, dx=dx, threads=threads, **options)
    except RuntimeError as e:
        print(f"  {code} {method}: failed: {e}", file=sys.stderr)
        return []
    r.setdefault("precision", "f64")
    r["dx"] = dx
    print(row(r), flush=True)
    return [r]


def _row(r: dict) -> str:
    stages = r.get("stage_median_s")
    split = ""
    if stages:
        split = "  " + " ".join(f"{k}={v * 1e3:.1f}ms" for k, v in stages.items())
        if r.get("untimed_s_per_step") is not None:
            split += f" untimed={r['untimed_s_per_step'] * 1e3:.1f}ms/step"
    nb = r.get("neighbours")
    nb_text = f"{nb:5.1f}" if isinstance(nb, (int, float)) else "    -"
    where = "cuda     " if r.get("backend") == "cuda" else f"threads={r['threads']}"
    where += " walk " if r.get("neighbour_search") == "walk" else ""
    where += f" cells=H/{r['cells_per_support']}" if r.get("cells_per_support", 1) != 1 else ""
    if r.get("neighbour_skin"):
        where += f" skin={r['neighbour_skin']:g} ({r['list_builds']} builds)"
    rate = f" {r['steps_per_s']:7.1f} steps/s" if r.get("backend") == "cuda" else ""
    memory = ""
    for key, label in (("host_bytes_per_particle", "host"), ("device_bytes_per_particle", "device")):
        if r.get(key) is not None:
            memory += f" {label}={r[key]:.0f}B/particle"
    return (f"{r['code']:>13} {r['method']:>6} {r.get('precision', 'f64'):>4} {where} "
            f"N={r['particles']:>8} nbrs={nb_text} {r['particle_steps_per_s']:10.3e} particle-steps/s{rate}"
            f"{memory}{split}")


def _print_walk_ratios(results: list[dict]):
    """Cell walk / neighbour lists, the same case side by side (sph bench --neighbours lists walk)."""
    walks = [r for r in results if r.get("neighbour_search") == "walk"]
    pairs = [(w, l) for w in walks for l in results if l.get("neighbour_search") == "lists"
             and all(l[k] == w[k] for k in ("precision", "threads", "backend", "particles"))]
    if pairs:
        print("\ncell walk / neighbour lists (same case, same run):")
    for w, l in pairs:
        print(f"  {w['backend']} {w['precision']} threads={w['threads']} N={w['particles']}: "
              f"{w['particle_steps_per_s'] / l['particle_steps_per_s']:.3f}x")


def _print_skin_ratios(results: list[dict]):
    """Reused lists / a list a step, the same case side by side (sph bench --skins 0 0.1): in
    particle-steps per second, or with --until in simulated seconds per wall second."""
    same = ("method", "precision", "threads", "backend", "particles", "neighbour_search", "until_s")
    one = [r for r in results if r.get("code") == "sphfluid" and "peers" not in r]
    pairs = [(s, z) for s in one if s.get("neighbour_skin") for z in one
             if z.get("neighbour_skin") == 0.0 and all(z.get(k) == s.get(k) for k in same)]
    if pairs:
        print("\nreused lists (run.neighbour_skin) / a list a step (same case, same run):")
    for s, z in pairs:
        speed = "sim_s_per_wall_s" if "until_s" in s else "particle_steps_per_s"
        print(f"  {s['method']} {s['precision']} threads={s['threads']} N={s['particles']} skin={s['neighbour_skin']:g}: "
              f"{s[speed] / z[speed]:.3f}x ({s['list_builds']} list builds in {s['steps']} steps)")


def _print_ratios(results: list[dict]):
    ours = [r for r in results if r["code"] == "sphfluid" and r.get("neighbour_search", "lists") == "lists"]
    theirs = [r for r in results if r["code"] != "sphfluid"]
    if not theirs:
        return
    print("\nratios (ours / reference, same dx, steps and threads):")
    for t in theirs:
        for precision in ("f32", "f64"):
            match = [o for o in ours if o["threads"] == t["threads"] and o["precision"] == precision
                     and abs(o["dx"] - t["dx"]) < 1e-12]
            for o in match:
                skin = f" skin={o['neighbour_skin']:g}" if o.get("neighbour_skin") else ""
                print(f"  ours {precision}{skin} vs {t['code']} {t['method']} threads={t['threads']} "
                      f"N={o['particles']}/{t['particles']}: "
                      f"{o['particle_steps_per_s'] / t['particle_steps_per_s']:.2f}x")


FRAME_S = 1.0 / 60.0  # seed 001's real-time figure: the particles one 16.67 ms frame (60 per second) can step


def frame_budget(results: list[dict]) -> list[dict]:
    """Per backend, precision and thread count of this run's own cases: about how many particles fit
    in one 16.67 ms step, from the measured steps/s (particle-steps/s x 16.67 ms, taken from the case
    whose step time is nearest 16.67 ms, since the rate per particle changes with N); ``measured``
    says whether cases on both sides of 16.67 ms were run (else it is extrapolated)."""
    out = []
    groups = {}
    for r in results:
        if r.get("code") == "sphfluid" and "peers" not in r and r.get("steps_per_s"):
            groups.setdefault((r.get("backend", "cpu"), r["precision"], r["threads"]), []).append(r)
    for (backend, precision, threads), cases in groups.items():
        near = min(cases, key=lambda r: abs(np.log(FRAME_S * r["steps_per_s"])))
        step_s = [1.0 / r["steps_per_s"] for r in cases]
        out.append({"backend": backend, "device": near.get("device", backend), "precision": precision,
                    "threads": threads, "particles": int(near["particle_steps_per_s"] * FRAME_S),
                    "from_particles": near["particles"], "from_step_ms": 1e3 / near["steps_per_s"],
                    "measured": min(step_s) <= FRAME_S <= max(step_s)})
    return out


def _print_frame_budget(budget: list[dict]):
    if not budget:
        return
    print(f"\nparticles in one {FRAME_S * 1e3:.2f} ms step (60 steps/s, seed 001's real-time figure), from the "
          "measured steps/s:")
    for b in budget:
        where = b["device"] if b["backend"] == "cuda" else f"cpu threads={b['threads']}"
        how = "between the sizes run" if b["measured"] else "extrapolated: run sizes on both sides of it"
        print(f"  {where} {b['precision']}: about {b['particles']:,} particles (N={b['from_particles']:,} took "
              f"{b['from_step_ms']:.2f} ms per step; {how})")


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()
