"""``sph study``: what each accuracy knob costs and what it buys, measured in one run.

For each validation case (``launch/validate.py``) the study runs a baseline and varies one knob at a
time around it — kernel family x resolution as a grid, then precision, CFL number and solver (the
incompressible DFSPH at one or two density tolerances) at every resolution — and records the case's error and the wall time of the stepping loop. The time is
reported per simulated second (what a user pays for a given physical duration) and as
particle-steps/s. It also times each optional term on a 3D dam break against the same run without
it. Results go to OUT/study.json, OUT/pareto.png (error against cost; the Pareto front of each case
drawn through its best points) and OUT/study.md (tables and the cheapest setting per error budget);
``--docs`` also updates docs/ACCURACY.md between its ``study`` markers and copies the plot to
docs/img/.
"""
from __future__ import annotations

import json
import logging
import shutil
import time
from datetime import datetime, timezone
from pathlib import Path

import numba
import numpy as np

from launch.bench import DEFAULT_SCENE, _cpu_name, spacing_for
from launch.validate import CaseOptions, dam_break, oscillating_drop, taylor_green

log = logging.getLogger("sph.study")
ROOT = Path(__file__).resolve().parent.parent

# per case: the function, the metric(s) whose maximum is the case's error, the resolutions swept
# (coarse to fine), and overrides that let the CFL number (not a cap on dt) set the step
CASES = {
    "oscillating_drop": (oscillating_drop, ("oscillating_drop.period_relative", "oscillating_drop.amplitude_relative"),
                         (0.1, 0.05, 0.025), ("time.dt=0.1",)),
    "dam_break": (dam_break, ("dam_break.front_rms_shifted",), (0.02, 0.01), ("time.dt=0.1",)),
    "taylor_green": (taylor_green, ("taylor_green.speed_l1_relative",), (0.02, 0.01), ("time.dt=0.1",)),
}
KERNELS = ("wendland_c2", "cubic_spline", "muller")
BASE = {"solver": "wcsph", "kernel": "wendland_c2", "precision": "f64", "cfl": 0.25, "tolerance": None}
# DFSPH's density tolerances (sph.density_tolerance); the step is its own CFL step on the flow speed
DFSPH_TOLERANCES = (1e-3, 1e-4)
BUDGETS = (0.01, 0.02, 0.05, 0.10, 0.20)


def plan(case: str, quick: bool) -> list[dict]:
    """The configurations of one case: kernel x resolution at the baseline, then precision, CFL and
    the DFSPH solver at every resolution for the baseline kernel. ``quick``: the coarsest resolution
    only, kernels, one CFL variation and one DFSPH tolerance (for tests)."""
    dxs = CASES[case][2][:1] if quick else CASES[case][2]
    configs = [dict(BASE, kernel=k, dx=dx) for dx in dxs for k in KERNELS]
    configs += [dict(BASE, precision="f32", dx=dx) for dx in dxs]
    cfls = (0.4,) if quick else (0.1, 0.4)
    configs += [dict(BASE, cfl=c, dx=dx) for dx in dxs for c in cfls]
    tolerances = DFSPH_TOLERANCES[:1] if quick else DFSPH_TOLERANCES
    configs += [dict(BASE, solver="dfsph", tolerance=tol, dx=dx) for dx in dxs for tol in tolerances]
    return configs


def overrides(cfg: dict) -> tuple:
    """The --set strings of one configuration. DFSPH runs with the symplectic Euler step (the scenes
    that use leapfrog are switched: DFSPH's step is a kick-solve-drift)."""
    out = (f"sph.kernel='{cfg['kernel']}'", f"time.cfl={cfg['cfl']}", f"sph.solver='{cfg['solver']}'")
    if cfg["solver"] == "dfsph":
        out += (f"sph.density_tolerance={cfg['tolerance']}", "time.integrator='symplectic_euler'",
                "sph.density='summation'")
    return out


def run_config(case: str, cfg: dict) -> dict:
    fn, metric_names, _, extra = CASES[case]
    opts = CaseOptions(precision=cfg["precision"], dx=cfg["dx"], plot=False, overrides=(*overrides(cfg), *extra))
    t0 = time.perf_counter()
    try:
        metrics = {m.name: float(m.value) for m in fn(True, Path("."), opts=opts)}
        error = max(metrics[n] for n in metric_names)
        outcome = "ok"
    except Exception as e:  # noqa: BLE001 - an unstable setting is a result of the study, not a crash
        metrics, error, outcome = {}, float("nan"), f"stopped: {e}"
    st = opts.stats
    wall = st.get("wall_s", float("nan"))
    sim_time = st.get("sim_time", float("nan"))
    return dict(cfg, case=case, error=error, metrics=metrics, outcome=outcome, particles=st.get("particles"),
                steps=st.get("steps"), wall_s=wall, sim_time=sim_time,
                wall_per_sim_s=wall / sim_time if sim_time and sim_time > 0 else float("nan"),
                particle_steps_per_s=(st["particles"] * st["steps"] / wall) if st.get("steps") and wall > 0 else None,
                iterations=(st["density_iterations"], st.get("divergence_iterations", 0.0))
                if "density_iterations" in st else None,
                total_s=time.perf_counter() - t0)


def term_costs(particles: int = 20_000, steps: int = 40) -> list[dict]:
    """Median step time of the 3D dam break with each optional term on, against the same run with
    all of them off (whose step list does not contain them at all)."""
    from sphcore.scene import load_scene
    from sphcore.solver import Simulation
    dx = spacing_for(DEFAULT_SCENE, particles)
    base = [f"particles.spacing={dx!r}", "time.mode='fixed'", "time.dt=1e-4"]
    variants = {"none (baseline)": [], "xsph": ["terms.xsph=0.3"], "surface_tension": ["terms.surface_tension=0.05"],
                "vorticity_confinement": ["terms.vorticity_confinement=0.01"],
                "continuity density (delta-SPH)": ["sph.density='continuity'"],
                "central force field": ["forces.central_omega=1.0"]}
    out = []
    for name, extra in variants.items():
        sim = Simulation(load_scene(DEFAULT_SCENE, base + extra), "f64")
        sim.step()
        sim.timers.reset()
        walls = []
        for _ in range(steps):
            t0 = time.perf_counter()
            sim.step()
            walls.append(time.perf_counter() - t0)
        stages = {k: v["median_s"] for k, v in sim.timers.summary().items()}
        out.append({"term": name, "particles": sim.n_particles, "step_median_s": float(np.median(walls)),
                    "stages": sorted(stages)})
    base_s = out[0]["step_median_s"]
    for r in out:
        r["ratio"] = r["step_median_s"] / base_s
    return out


def pareto(points: list[tuple[float, float]]) -> list[int]:
    """Indices of the points no other point beats on both cost and error (both lower is better)."""
    keep = []
    for i, (c, e) in enumerate(points):
        if not np.isfinite(c) or not np.isfinite(e):
            continue
        if not any((c2 <= c and e2 <= e and (c2 < c or e2 < e)) for j, (c2, e2) in enumerate(points)
                   if j != i and np.isfinite(c2) and np.isfinite(e2)):
            keep.append(i)
    return sorted(keep, key=lambda i: points[i][0])


def _label(r: dict) -> str:
    solver = f"DFSPH tol {r['tolerance']:g}" if r["solver"] == "dfsph" else "WCSPH"
    return f"{solver}, {r['kernel']}, dx={r['dx']:g}, {r['precision']}, CFL {r['cfl']:g}"


def plot(results: list[dict], path: Path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    cases = list(dict.fromkeys(r["case"] for r in results))
    fig, axes = plt.subplots(1, len(cases), figsize=(5 * len(cases), 4.2), squeeze=False)
    markers = {"wendland_c2": "o", "cubic_spline": "s", "muller": "^"}
    for ax, case in zip(axes[0], cases):
        rs = [r for r in results if r["case"] == case and r["outcome"] == "ok"]
        for r in rs:
            colour = ("tab:red" if r["solver"] == "dfsph" else "tab:orange" if r["precision"] == "f32" else
                      "tab:green" if r["cfl"] != BASE["cfl"] else "tab:blue")
            ax.loglog(r["wall_per_sim_s"], r["error"], markers[r["kernel"]], color=colour, mfc="none", ms=7)
            ax.annotate(f"{r['dx']:g}", (r["wall_per_sim_s"], r["error"]), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")
        front = pareto([(r["wall_per_sim_s"], r["error"]) for r in rs])
        ax.loglog([rs[i]["wall_per_sim_s"] for i in front], [rs[i]["error"] for i in front], "k-", lw=1,
                  label="Pareto front")
        ax.set_title(case)
        ax.set_xlabel("wall seconds per simulated second (2 cores)")
        ax.set_ylabel("relative error")
        ax.grid(True, which="both", alpha=0.3)
    from matplotlib.lines import Line2D
    handles = [Line2D([], [], marker=m, ls="", mfc="none", color="k", label=k) for k, m in markers.items()]
    handles += [Line2D([], [], marker="o", ls="", color=c, label=t) for c, t in
                (("tab:blue", "f64, CFL 0.25"), ("tab:orange", "float32"), ("tab:green", "CFL 0.1 / 0.4"),
                 ("tab:red", "DFSPH"))]
    handles.append(Line2D([], [], color="k", label="Pareto front"))
    axes[0][-1].legend(handles=handles, fontsize=7, loc="upper right")
    fig.suptitle("Error against cost (numbers: spacing dx in m)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def report_markdown(results: list[dict], terms: list[dict], meta: dict, image: str) -> str:
    lines = [f"Command: `{meta['command']}` — {meta['date']}, {meta['machine']}.", "",
             f"![error against cost]({image})", ""]
    for case in dict.fromkeys(r["case"] for r in results):
        rs = [r for r in results if r["case"] == case]
        lines += [f"### {case}", "", "| solver | kernel | dx (m) | precision | CFL | particles | error | "
                  "wall s per sim s | work (1e6 particle-steps per sim s) | particle-steps/s | "
                  "iterations/step (density, divergence) | outcome |",
                  "|---|---|---:|---|---:|---:|---:|---:|---:|---:|---|---|"]
        for r in rs:
            pss = f"{r['particle_steps_per_s']:.3g}" if r["particle_steps_per_s"] else "-"
            work = (f"{r['particles'] * r['steps'] / r['sim_time'] / 1e6:.3g}"
                    if r.get("steps") and r.get("sim_time") else "-")
            solver = f"dfsph (tol {r['tolerance']:g})" if r["solver"] == "dfsph" else r["solver"]
            its = f"{r['iterations'][0]:.1f}, {r['iterations'][1]:.1f}" if r.get("iterations") else "-"
            lines.append(f"| {solver} | {r['kernel']} | {r['dx']:g} | {r['precision']} | {r['cfl']:g} | "
                         f"{r['particles'] or '-'} | {r['error']:.3g} | {r['wall_per_sim_s']:.3g} | {work} | {pss} | "
                         f"{its} | {r['outcome'][:60]} |")
        ok = [r for r in rs if r["outcome"] == "ok" and np.isfinite(r["error"])]
        lines += ["", "Cheapest setting for an error budget:", ""]
        for budget in BUDGETS:
            within = [r for r in ok if r["error"] <= budget]
            if within:
                best = min(within, key=lambda r: r["wall_per_sim_s"])
                lines.append(f"- {budget:.0%}: {_label(best)} — {best['wall_per_sim_s']:.3g} s per simulated "
                             f"second (error {best['error']:.2%})")
            else:
                lines.append(f"- {budget:.0%}: not reached by any setting studied")
        lines.append("")
    if terms:
        lines += ["### Optional terms", "", f"3D dam break, {terms[0]['particles']} particles, float64, median step "
                  "time over the timed steps; a term that is off is not in the step's stage list at all.", "",
                  "| term | median step (ms) | vs baseline | stages |", "|---|---:|---:|---|"]
        for t in terms:
            lines.append(f"| {t['term']} | {t['step_median_s'] * 1e3:.2f} | {t['ratio']:.3f}x | "
                         f"{', '.join(t['stages'])} |")
        lines.append("")
    return "\n".join(lines)


def run_study(cases: list[str], quick: bool, out: Path, docs: bool, with_terms: bool = True) -> int:
    out.mkdir(parents=True, exist_ok=True)
    import sys
    meta = {"date": datetime.now(timezone.utc).strftime("%Y-%m-%d"), "command": "sph " + " ".join(sys.argv[1:]),
            "machine": f"{_cpu_name()}, {numba.config.NUMBA_NUM_THREADS} cores, {numba.get_num_threads()} numba threads"}
    results = []
    todo = [(c, cfg) for c in cases for cfg in plan(c, quick)]
    for k, (case, cfg) in enumerate(todo, 1):
        r = run_config(case, cfg)
        results.append(r)
        print(f"[{k}/{len(todo)}] {case:<17} {_label(r):<45} error {r['error']:9.3g}  "
              f"{r['wall_per_sim_s']:8.3g} s/sim-s  {r['outcome'][:50]}", flush=True)
    terms = term_costs() if with_terms and not quick else []
    for t in terms:
        print(f"term {t['term']:<24} {t['step_median_s'] * 1e3:8.2f} ms/step  {t['ratio']:.3f}x", flush=True)
    (out / "study.json").write_text(json.dumps({"meta": meta, "results": results, "terms": terms}, indent=2) + "\n")
    plot(results, out / "pareto.png")
    image = "pareto.png"
    if docs:
        shutil.copy(out / "pareto.png", ROOT / "docs" / "img" / "pareto.png")
        image = "img/pareto.png"
    text = report_markdown(results, terms, meta, image)
    (out / "study.md").write_text(text + "\n")
    if docs:
        _update_accuracy_doc(text)
    print(f"wrote {out}/study.json, pareto.png, study.md" + (" and docs/ACCURACY.md" if docs else ""))
    return 0


BEGIN, END = "<!-- study:begin -->", "<!-- study:end -->"


def _update_accuracy_doc(text: str):
    path = ROOT / "docs" / "ACCURACY.md"
    doc = path.read_text() if path.exists() else "# Accuracy and cost\n"
    block = f"{BEGIN}\n{text}\n{END}"
    if BEGIN in doc and END in doc:
        doc = doc[: doc.index(BEGIN)] + block + doc[doc.index(END) + len(END):]
    else:
        doc = doc.rstrip() + "\n\n## The speed/accuracy trade\n\n" + block + "\n"
    path.write_text(doc)
