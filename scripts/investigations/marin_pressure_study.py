"""MARIN's dam break against a box (configs/dam_break_obstacle.toml): the pressure on the box's face,
P1-P4, through the first impact (t = 0-1.45 s), for one set of scene overrides.

    python scripts/investigations/marin_pressure_study.py LABEL [SECTION.KEY=VALUE ...]

Steps the scene (the file's H0 / 15 unless an override sets particles.spacing) to 1.45 s, sampling
the probes every step, and prints per sensor the case's measures (`sph validate dam_break_obstacle`:
the peak of the 10 ms moving average and the impulse over 0.35-1.4 s, both against the record) and
what the case does not score: the ringing after the impact, as the RMS of the probe about its own
50 ms moving average over 0.6-1.4 s and the frequency that carries most of that ringing's power; the
times the surge reaches the gauges H3 and H2 (h > 0.02 m) and each sensor rises past MARIN_RISE_PA
(1 kPa), against the records. About 1 minute at H0 / 15 and 7.5 at H0 / 25 on 2 cores.
Writes the probe record to /tmp/marin_<LABEL>.npz. docs/VALIDATION.md (the MARIN section) quotes it.
"""
import sys
import time

import numpy as np

from launch.validate import (CONFIGS, MARIN_RISE_PA, MARIN_SENSORS, load_marin, load_marin_pressure,
                             moving_average, pressure_measures, probe_record, rise_time)
from sphcore.scene import load_scene
from sphcore.solver import Simulation

END_S = 1.45
RING = (0.6, 1.4)     # s: after the impact, the plateau the experiment reads
SMOOTH_S = 0.050      # s: the slow part the ringing is measured about


WET_M = 0.02          # m: a gauge's arrival, the first time it reads more (the case's measure)


def ringing(t, p):
    """(RMS of p about its SMOOTH_S moving average over RING, the frequency in Hz of that residue's
    largest power, on an even resampling)."""
    grid = np.arange(RING[0], RING[1], 1e-4)
    residue = np.interp(grid, t, p - moving_average(t, p, SMOOTH_S))
    power = np.abs(np.fft.rfft(residue * np.hanning(grid.size))) ** 2
    freq = np.fft.rfftfreq(grid.size, 1e-4)
    keep = freq > 5.0
    return float(np.sqrt(np.mean(residue ** 2))), float(freq[keep][np.argmax(power[keep])])


def main(label, overrides):
    scene = load_scene(CONFIGS / "dam_break_obstacle.toml", ["output.probes_every=1", *overrides])
    sim = Simulation(scene)
    names = sim.probes.names
    start = time.perf_counter()
    rec = probe_record(sim, END_S, None)
    wall = time.perf_counter() - start
    np.savez(f"/tmp/marin_{label}.npz", rec=rec, names=np.array(names))
    t_exp, p_exp = load_marin_pressure()
    print(f"{label}: {' '.join(overrides) or '(the scene as it is)'}; {sim.n_particles} particles, "
          f"H0 / {0.55 / scene.particles.spacing:.0f}, c0 {scene.sph.sound_speed:g} m/s, {wall:.0f} s")
    t_h, h_exp = load_marin()
    arrivals = ", ".join(f"{g} {rise_time(rec[:, 0], rec[:, 1 + names.index(g)], WET_M):.3f} s "
                         f"(MARIN {rise_time(t_h, h_exp[g], WET_M):.3f})" for g in ("H3", "H2"))
    print(f"the surge's arrival (h > {WET_M:g} m): {arrivals}")
    print(f"rises: the first time past {MARIN_RISE_PA:g} Pa")
    print("sensor  rise (s)  MARIN  peak 10 ms (Pa)  vs MARIN  impulse (Pa s)  vs MARIN  ringing RMS (Pa)  at (Hz)  "
          "MARIN's RMS (Pa)")
    for sensor in MARIN_SENSORS:
        p = rec[:, 1 + names.index(sensor)]
        peak, _, _, _, impulse = pressure_measures(rec[:, 0], p)
        peak_e, _, _, _, impulse_e = pressure_measures(t_exp, p_exp[sensor])
        rms, hz = ringing(rec[:, 0], p)
        rms_e, _ = ringing(t_exp, p_exp[sensor])
        rise, rise_e = rise_time(rec[:, 0], p), rise_time(t_exp, p_exp[sensor])
        print(f"{sensor:6}  {rise:7.3f}  {rise_e:7.3f}  {peak:15.0f}  {peak / peak_e - 1:+8.1%}  {impulse:14.0f}  "
              f"{impulse / impulse_e - 1:+8.1%}  {rms:16.0f}  {hz:7.1f}  {rms_e:16.0f}")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
