"""Another SPH code's runs of Buchner's dam break, read with this case's metrics: how far is its wall
pressure from the experiment's at P1 and P2?

TrixiParticles.jl kept reference runs of the case (WCSPH, continuity density with Molteni &
Colagrossi's density diffusion, delta = 0.1, Wendland C2, c0 = 20 sqrt(g H), H = 0.6 m; dummy-particle
walls; each sensor the mean of 10 points over 9 mm whose top is the experiment's sensor centre) at
H / 40, H / 80 and H / 320: validation/dam_break_2d/validation_reference_wcsph_{0015,00075,0001875}.json
at commit 0c554cd1a3e08b11b0114606709e4684b6a72bcd of github.com/trixi-framework/TrixiParticles.jl
(later commits moved the sensors). Give the folder holding those three files (from a checkout of that
commit, e.g. `git show 0c554cd:validation/dam_break_2d/FILE > FILE`):

    .venv/bin/python scripts/investigations/buchner_other_code.py FOLDER

It prints, per file, the peak and impulse of p* = p / (rho g H) over this case's windows (P1: t* 2-4,
P2: t* 3.1-7; launch/validate.py dam_break_pressure) and P1 at a few times. The runs were sampled
every 0.08 t*, too sparse to catch an impact's peak; the impulse does not need the peak.
"""
import argparse
import json
import math
from pathlib import Path

import numpy as np

from launch.validate import PRESSURE_WINDOWS, load_buchner, peak_and_impulse

FILES = {"H / 40": "validation_reference_wcsph_0015.json", "H / 80": "validation_reference_wcsph_00075.json",
         "H / 320": "validation_reference_wcsph_0001875.json"}
H, G, RHO = 0.6, 9.81, 1000.0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", type=Path, help="the folder holding the three reference files")
    folder = ap.parse_args().folder
    experiment = load_buchner()
    print("| run | P1 peak (t*) | P1 impulse | P2 peak (t*) | P2 impulse | P1 at t* 2.75, 3.0, 3.5, 4.0 |")
    print("|---|---|---|---|---|---|")
    rows = [("Buchner (experiment)", {s: experiment[s] for s in ("P1", "P2")})]
    for name, file in FILES.items():
        data = json.loads((folder / file).read_text())
        series = {}
        for sensor in ("P1", "P2"):
            s = data[f"pressure_{sensor}_fluid_1"]
            series[sensor] = (np.array(s["time"]) * math.sqrt(G / H), np.array(s["values"], dtype=float) / (RHO * G * H))
        rows.append((f"TrixiParticles WCSPH, {name}", series))
    for name, series in rows:
        cells = []
        for sensor in ("P1", "P2"):
            peak, when, impulse = peak_and_impulse(*series[sensor], *PRESSURE_WINDOWS[sensor])
            cells += [f"{peak:.3f} ({when:.2f})", f"{impulse:.3f}"]
        t, p = series["P1"]
        cells.append(", ".join(f"{np.interp(x, t, p):.2f}" for x in (2.75, 3.0, 3.5, 4.0)))
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
