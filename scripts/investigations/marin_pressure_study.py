"""MARIN's dam break against a box (configs/dam_break_obstacle.toml): the pressure on the box's face,
P1-P4, through the first impact (t = 0-1.45 s), for one set of scene overrides.

    python scripts/investigations/marin_pressure_study.py LABEL [SECTION.KEY=VALUE ...]
    python scripts/investigations/marin_pressure_study.py --reuse LABEL   # the figures of a saved run

Steps the scene (the file's H0 / 15 unless an override sets particles.spacing) to 1.45 s, sampling
the probes every step, and prints per sensor the case's measures (`sph validate dam_break_obstacle`:
the peak of the 10 ms moving average and the impulse over 0.35-1.4 s, both against the record) and
what the case does not score: the ringing after the impact, as the RMS of the probe about its own
50 ms moving average over 0.6-1.4 s and the frequency that carries most of that ringing's power; the
times the surge reaches the gauges H3 and H2 (h > 0.02 m) and each sensor rises past MARIN_RISE_PA
(1 kPa), against the records; how thin the front is at H3 (its arrival at 0.5, 2 and 4 cm), how far
the reservoir gauge H4 strays from the record to 1.4 s, and the gaps between P1's spikes over
0.42-0.56 s (local maxima above 30 % of the largest). About 1 minute at H0 / 15 and 7.5 at H0 / 25 on
2 cores. Writes the probe record to /tmp/marin_<LABEL>.npz; --reuse reads it back instead of running.
docs/VALIDATION.md (the MARIN section) quotes it.
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
FRONT_M = (0.005, 0.02, 0.04)  # m: the levels whose arrivals at H3 say how thin the front is
SPIKES = (0.42, 0.56)  # s: P1's first impact


def ringing(t, p):
    """(RMS of p about its SMOOTH_S moving average over RING, the frequency in Hz of that residue's
    largest power, on an even resampling)."""
    grid = np.arange(RING[0], RING[1], 1e-4)
    residue = np.interp(grid, t, p - moving_average(t, p, SMOOTH_S))
    power = np.abs(np.fft.rfft(residue * np.hanning(grid.size))) ** 2
    freq = np.fft.rfftfreq(grid.size, 1e-4)
    keep = freq > 5.0
    return float(np.sqrt(np.mean(residue ** 2))), float(freq[keep][np.argmax(power[keep])])


def spike_gaps(t, p):
    """ms between the local maxima of p over SPIKES that exceed 30 % of its largest there."""
    inside = (t > SPIKES[0]) & (t < SPIKES[1])
    tt, pp = t[inside], p[inside]
    at = [k for k in range(1, len(pp) - 1) if pp[k] > pp[k - 1] and pp[k] >= pp[k + 1] and pp[k] > 0.3 * pp.max()]
    return [1e3 * (tt[b] - tt[a]) for a, b in zip(at, at[1:])]


def run(label, overrides):
    """Run the scene with ``overrides``, save its probe record; (record, probe names)."""
    scene = load_scene(CONFIGS / "dam_break_obstacle.toml", ["output.probes_every=1", *overrides])
    sim = Simulation(scene)
    start = time.perf_counter()
    rec = probe_record(sim, END_S, None)
    wall = time.perf_counter() - start
    np.savez(f"/tmp/marin_{label}.npz", rec=rec, names=np.array(sim.probes.names))
    print(f"{label}: {' '.join(overrides) or '(the scene as it is)'}; {sim.n_particles} particles, "
          f"H0 / {0.55 / scene.particles.spacing:.0f}, c0 {scene.sph.sound_speed:g} m/s, {wall:.0f} s")
    return rec, list(sim.probes.names)


def main(label, overrides, reuse=False):
    if reuse:
        saved = np.load(f"/tmp/marin_{label}.npz", allow_pickle=False)
        rec, names = saved["rec"], [str(n) for n in saved["names"]]
        print(f"{label}: the record saved in /tmp/marin_{label}.npz")
    else:
        rec, names = run(label, overrides)
    t_exp, p_exp = load_marin_pressure()
    t_h, h_exp = load_marin()
    column = {name: rec[:, 1 + k] for k, name in enumerate(names)}
    arrivals = ", ".join(f"{g} {rise_time(rec[:, 0], column[g], WET_M):.3f} s "
                         f"(MARIN {rise_time(t_h, h_exp[g], WET_M):.3f})" for g in ("H3", "H2"))
    print(f"the surge's arrival (h > {WET_M:g} m): {arrivals}")
    front = ", ".join(f"{100 * level:g} cm {rise_time(rec[:, 0], column['H3'], level):.3f} s "
                      f"(MARIN {rise_time(t_h, h_exp['H3'], level):.3f})" for level in FRONT_M)
    print(f"H3's front: {front}")
    early = t_h <= 1.4
    stray = np.interp(t_h[early], rec[:, 0], np.nan_to_num(column["H4"])) - h_exp["H4"][early]
    print(f"H4 against the record to 1.4 s: {stray.min():+.4f} to {stray.max():+.4f} m")
    print("P1's spikes over {:g}-{:g} s, gaps (ms): {}".format(
        *SPIKES, " ".join(f"{g:.1f}" for g in spike_gaps(rec[:, 0], column["P1"]))))
    print(f"rises: the first time past {MARIN_RISE_PA:g} Pa")
    print("sensor  rise (s)  MARIN  peak 10 ms (Pa)  vs MARIN  impulse (Pa s)  vs MARIN  ringing RMS (Pa)  at (Hz)  "
          "MARIN's RMS (Pa)")
    for sensor in MARIN_SENSORS:
        p = column[sensor]
        peak, _, _, _, impulse = pressure_measures(rec[:, 0], p)
        peak_e, _, _, _, impulse_e = pressure_measures(t_exp, p_exp[sensor])
        rms, hz = ringing(rec[:, 0], p)
        rms_e, _ = ringing(t_exp, p_exp[sensor])
        rise, rise_e = rise_time(rec[:, 0], p), rise_time(t_exp, p_exp[sensor])
        print(f"{sensor:6}  {rise:7.3f}  {rise_e:7.3f}  {peak:15.0f}  {peak / peak_e - 1:+8.1%}  {impulse:14.0f}  "
              f"{impulse / impulse_e - 1:+8.1%}  {rms:16.0f}  {hz:7.1f}  {rms_e:16.0f}")


if __name__ == "__main__":
    if sys.argv[1] == "--reuse":
        main(sys.argv[2], [], reuse=True)
    else:
        main(sys.argv[1], sys.argv[2:])
