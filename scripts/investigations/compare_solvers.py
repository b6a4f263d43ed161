"""WCSPH against DFSPH on validation cases, side by side in one run: error, wall time, steps,
iterations. Prints a Markdown table (docs/ACCURACY.md, "WCSPH or DFSPH").

    python scripts/investigations/compare_solvers.py [--cases dam_break hydrostatic] [--out runs/solvers]
"""
import argparse
from pathlib import Path

from launch.validate import CASES, CaseOptions

# (label, overrides) per case: WCSPH as the case ships; DFSPH with the step bound by the flow speed
# (time.dt raised from the scene's cap) at two density tolerances
VARIANTS = {
    "dam_break": [("WCSPH (c0 = 30 m/s)", ()),
                  ("DFSPH, tolerance 1e-3", ("sph.solver=dfsph", "time.dt=0.004", "sph.density_tolerance=1e-3")),
                  ("DFSPH, tolerance 1e-4", ("sph.solver=dfsph", "time.dt=0.004", "sph.density_tolerance=1e-4"))],
    "hydrostatic": [("WCSPH, continuity + delta-SPH (c0 = 31.3 m/s)", ()),
                    ("WCSPH, summation density", ("sph.density=summation",)),
                    ("DFSPH, tolerance 1e-4", ("sph.solver=dfsph", "sph.density=summation", "time.dt=0.001",
                                               "sph.density_tolerance=1e-4")),
                    ("DFSPH, tolerance 1e-5", ("sph.solver=dfsph", "sph.density=summation", "time.dt=0.001",
                                               "sph.density_tolerance=1e-5",
                                               "sph.max_iterations=1000"))],
}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--out", type=Path, default=Path("runs/solvers"))
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    print("| case (quick) | solver | metric | value | steps | mean dt (s) | iterations/step (density, divergence) "
          "| wall s | wall vs WCSPH |")
    print("|---|---|---|---|---|---|---|---|---|")
    for case in args.cases:
        base = None
        for label, overrides in VARIANTS[case]:
            opts = CaseOptions(overrides=overrides, plot=False)
            try:
                metrics = CASES[case](True, args.out, "cpu", opts)
                m = metrics[0]
                value = f"{m.value:.4g} ({'PASS' if m.passed else 'FAIL'})"
                name = m.name
            except Exception as exc:  # noqa: BLE001 - a blow-up is a result here
                name, value = "-", f"stopped: {str(exc)[:80]}"
            st = opts.stats
            wall = st.get("wall_s", float("nan"))
            base = wall if base is None else base
            its = (f"{st['density_iterations']:.1f}, {st['divergence_iterations']:.1f}"
                   if "density_iterations" in st else "-")
            dt = st["sim_time"] / st["steps"] if st.get("steps") else float("nan")
            print(f"| {case} | {label} | {name} | {value} | {st.get('steps', '-')} | {dt:.3g} | {its} | {wall:.1f} | "
                  f"{wall / base:.2f} |", flush=True)


if __name__ == "__main__":
    main()
