"""sph validate dam_break_obstacle: MARIN's measured water heights and pressures (Kleefsman et al.
2005) load as copied, the gauges' and sensors' measures do what their docstrings say, and the quick
case runs and reports its metrics with verdicts that follow the values."""
import numpy as np
import pytest

from launch.cli import main
from launch.validate import (HEIGHT_TOLERANCE, MARIN_DATA, MARIN_END_S, MARIN_GAUGES, MARIN_H4_RETURN_S,
                             MARIN_PRESSURE_DATA, MARIN_PRESSURE_WINDOW, MARIN_SENSORS, PRESSURE_FILTER_S,
                             height_measures, load_marin, load_marin_pressure, pressure_measures, rise_time)
from sphcore.scene import load_scene

from conftest import CONFIGS, validation_lines


def _cites(path, commit: str) -> bool:
    """Whether a data file's comment header names the paper and the source's commit."""
    header = [line for line in path.read_text().splitlines() if line.startswith("#")]
    return any("Kleefsman" in line and "2005" in line for line in header) and any(commit in line for line in header)


def test_a_record_with_another_header_or_times_out_of_order_is_refused(tmp_path):
    bad = tmp_path / "record.csv"
    bad.write_text("# a comment\nt_s,P1_Pa,P2_Pa\n0.1,1,2\n")
    with pytest.raises(ValueError, match=r"header 't_s,P1_Pa,P2_Pa', expected 't_s,P1_Pa,P2_Pa,P3_Pa,P4_Pa'"):
        load_marin_pressure(bad)
    bad.write_text("t_s,H1_m,H2_m,H3_m,H4_m\n0.2,0,0,0,0.5\n0.1,0,0,0,0.5\n")
    with pytest.raises(ValueError, match="the times do not increase"):
        load_marin(bad)


def test_the_marin_records_load_as_copied():
    # Given the down-sampled copy (its header cites the paper, the source file and its commit)
    assert _cites(MARIN_DATA, "b2dffb32cd56e3eee14e2c6863ac4951ce9f29c8")
    # When it loads
    t, h = load_marin()
    # Then every row is there, in increasing time, about 50 a second over 0-7.38 s
    assert len(t) == 370 and np.all(np.diff(t) > 0.015) and np.all(np.diff(t) < 0.025)
    assert (t[0], t[-1]) == (0.00002, 7.38004)
    # rows checked by hand against the source (its columns: H3, H2, H1, H4)
    k = int(np.flatnonzero(t == 4.50004)[0])
    assert [h[g][k] for g in MARIN_GAUGES] == [0.15267, 0.14460, 0.27047, 0.25967]
    assert [h[g][0] for g in MARIN_GAUGES] == [0.00040, 0.00053, 0.00027, 0.54667]
    # and the surge wets the gauges in the order of their distance from the column: H3, H2, H1
    wet = {g: t[np.argmax(h[g] > 0.02)] for g in ("H1", "H2", "H3")}
    assert wet["H3"] < wet["H2"] < wet["H1"]
    # the window of every measure lies inside the record
    assert t[0] < 0.001 and MARIN_END_S < t[-1]


def test_the_marin_pressure_records_load_as_copied():
    # Given the copied rows (the header cites the paper, the source file and its commit)
    assert _cites(MARIN_PRESSURE_DATA, "665d90114a1720051144133a3a0acc2a4aaa7b2f")
    # When they load
    t, p = load_marin_pressure()
    # Then every row is there: ~1 kHz from 0.30 to 1.40 s, covering the window of the measures
    assert len(t) == 1100 and np.all(np.diff(t) > 0.00097) and np.all(np.diff(t) < 0.00102)
    assert (t[0], t[-1]) == (0.3000232199500781, 1.3990209742698942)
    assert t[0] < MARIN_PRESSURE_WINDOW[0] and MARIN_PRESSURE_WINDOW[1] - t[-1] < 0.0011
    # two rows checked by hand against the source: the first, and P1's raw peak (11,239 Pa at 0.415 s)
    assert [p[s][0] for s in MARIN_SENSORS] == [-24.8, -5.066666666666666, -50.06666666666667, -22.533333333333335]
    k = int(np.argmax(p["P1"]))
    assert t[k] == pytest.approx(0.415, abs=0.001) and p["P1"][k] == pytest.approx(11239, abs=1)
    # and the surge reaches the sensors from the floor up, P1 to P4
    wet = [t[np.argmax(p[s] > 500.0)] for s in MARIN_SENSORS]
    assert wet == sorted(wet) and 0.39 < wet[0] < wet[-1] < 0.44


def test_the_pressure_measures_of_a_made_up_record():
    t = np.arange(0.3, 1.5, 0.001)
    # a plateau of 3 kPa from 0.5 s with a 1 ms spike of 20 kPa at 0.6 s: the filter takes the spike
    # down to its 10 ms mean, the raw peak keeps it
    p = np.where(t >= 0.5, 3000.0, 0.0) + np.where(np.abs(t - 0.6) < 0.0005, 17000.0, 0.0)
    peak, when, raw, raw_when, impulse = pressure_measures(t, p)
    assert raw == pytest.approx(20000.0) and raw_when == pytest.approx(0.6, abs=0.001)
    assert peak == pytest.approx(3000.0 + 17000.0 * 0.001 / PRESSURE_FILTER_S, rel=0.05)
    assert when == pytest.approx(0.6, abs=0.006)
    lo, hi = MARIN_PRESSURE_WINDOW
    assert impulse == pytest.approx(3000.0 * (hi - 0.5) + 17000.0 * 0.001, rel=0.01)  # over the window only


def test_a_rise_is_the_first_sample_past_the_level():
    t = np.arange(0.3, 0.6, 0.001)
    p = np.where(t >= 0.45, 2000.0, np.where(t >= 0.4, 900.0, 0.0))
    assert rise_time(t, p) == pytest.approx(0.45, abs=1e-9)       # 900 Pa is not past 1 kPa
    assert rise_time(t, p, 500.0) == pytest.approx(0.4, abs=1e-9)
    assert np.isnan(rise_time(t, np.full_like(t, np.nan)))        # a dry sensor never rises
    # the record's sensors rise from the floor up, 17-39 ms apart (the note quotes them)
    t_e, p_e = load_marin_pressure()
    rises = [rise_time(t_e, p_e[s]) for s in MARIN_SENSORS]
    assert rises == sorted(rises) and rises[0] == pytest.approx(0.394, abs=0.001)


def test_the_gauge_measures_of_a_made_up_record():
    t = np.linspace(0.0, 7.0, 701)
    # a triangle 0.3 m high at 2 s, from 1 to 3 s; dry (nan) elsewhere
    h = np.where(np.abs(t - 2.0) < 1.0, 0.3 * (1.0 - np.abs(t - 2.0)), np.nan)
    peak, when, impulse, arrival = height_measures(t, h, "H2")
    assert (peak, when) == (pytest.approx(0.3), pytest.approx(2.0))
    assert impulse == pytest.approx(0.3)  # the triangle's area; the dry samples read 0
    assert arrival == pytest.approx(1.07, abs=0.011)  # the first sample above 0.02 m
    # past the window's end nothing counts: the same triangle at 6.5 s is half outside
    late = np.where(np.abs(t - 6.5) < 1.0, 0.3 * (1.0 - np.abs(t - 6.5)), 0.0)
    peak, when, impulse, _ = height_measures(t, late, "H1")
    assert when == pytest.approx(MARIN_END_S) and peak == pytest.approx(0.15)
    assert impulse == pytest.approx(0.5 * 0.5 * 0.15)  # the rising half-metre from 5.5 to 6 s only


def test_the_reservoir_gauge_peaks_on_the_returning_wave():
    t = np.linspace(0.0, 6.0, 601)
    # the still column at 0.55 m drains to 0.1 m and a wave comes back to 0.4 m at 4 s
    h = np.interp(t, [0.0, MARIN_H4_RETURN_S, 4.0, 6.0], [0.55, 0.1, 0.4, 0.2])
    peak, when, _, _ = height_measures(t, h, "H4")
    assert (peak, when) == (pytest.approx(0.4), pytest.approx(4.0))
    # a downstream gauge's peak is over the whole window
    assert height_measures(t, h, "H3")[:2] == (pytest.approx(0.55), pytest.approx(0.0))


def test_the_scene_is_the_experiment():
    scene = load_scene(CONFIGS / "dam_break_obstacle.toml")
    block = scene.fluid.blocks[0]
    assert list(block.min) == [1.992, 0.0, 0.0] and list(block.max) == [3.22, 0.55, 1.0]
    (box,) = scene.obstacles
    lo = np.subtract(box.center, np.multiply(box.size, 0.5))
    hi = np.add(box.center, np.multiply(box.size, 0.5))
    assert np.allclose(lo, [0.6635, 0.0, 0.2985]) and np.allclose(hi, [0.8245, 0.161, 0.7015])
    # the four gauges read as wire gauges, and their lines again by the highest wet point
    gauges, sensors = scene.probes[:8], scene.probes[8:]
    assert [p.name for p in gauges] == [*MARIN_GAUGES, *(f"{g}_highest" for g in MARIN_GAUGES)]
    lines = [(0.496, 0.0, 0.5), (0.992, 0.0, 0.5), (1.488, 0.0, 0.5), (2.638, 0.0, 0.5)]
    assert [tuple(p.at) for p in gauges] == lines + lines
    assert [p.gauge for p in gauges] == ["wire"] * 4 + ["highest"] * 4
    assert all(p.kind == "height" for p in gauges)
    # and the four pressure sensors on the box's face, from the floor up
    assert [p.name for p in sensors] == list(MARIN_SENSORS) and all(p.kind == "pressure" for p in sensors)
    assert [tuple(p.at) for p in sensors] == [(0.8245, y, 0.471) for y in (0.021, 0.061, 0.101, 0.141)]
    assert all(p.at[0] == hi[0] for p in sensors)  # on the face the water strikes


@pytest.mark.slow  # a 3D validation case (about four minutes on 2 cores): the slow tier
def test_the_quick_case_runs_and_reports_honest_verdicts(tmp_path, capsys):
    # When the quick case runs (H0 / 15, about 13,000 particles, 6 s of the flow)
    rc = main(["validate", "dam_break_obstacle", "--quick", "--out", str(tmp_path)])
    # Then every metric line is honest: a finite relative error against the case's tolerance, its
    # verdict and the exit code following the values
    lines = validation_lines(capsys.readouterr().out, "dam_break_obstacle", HEIGHT_TOLERANCE, rc)
    # and it prints the peak and the impulse of every gauge
    names = [line.split()[0] for line in lines]
    assert names == [f"dam_break_obstacle.{g}_{m}_relative" for g in (*MARIN_GAUGES, *MARIN_SENSORS)
                     for m in ("peak", "impulse")], names
    assert (tmp_path / "dam_break_obstacle.png").stat().st_size > 10_000
    assert (tmp_path / "dam_break_obstacle_pressure.png").stat().st_size > 10_000
