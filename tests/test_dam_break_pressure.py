"""sph validate dam_break_pressure: Buchner's (2002) digitised wall pressure loads as copied, the
filter and the window measures do what their docstrings say, and the quick case runs and reports
its metrics with verdicts that follow the values."""
import numpy as np
import pytest

from launch.cli import main
from launch.validate import (BUCHNER_DATA, PRESSURE_TOLERANCE, PRESSURE_WINDOWS, load_buchner, moving_average,
                             peak_and_impulse)

from conftest import validation_lines


def test_the_buchner_records_load_as_copied():
    # Given the data file copied from TrixiParticles.jl (its header cites the thesis and the paths)
    header = BUCHNER_DATA.read_text().splitlines()[:10]
    assert any("Buchner" in line and "2002" in line for line in header)
    assert any("exp_pressure_sensor_P1.csv" in line for line in header)
    # When it loads
    data = load_buchner()
    # Then both sensors are there, row for row, in increasing time
    assert set(data) == {"P1", "P2"}
    (t1, p1), (t2, p2) = data["P1"], data["P2"]
    assert len(t1) == 98 and len(t2) == 47
    assert (t1[0], p1[0]) == (2.02512, -0.01792) and (t1[-1], p1[-1]) == (7.29946, 0.41565)
    assert (t2[0], p2[0]) == (3.06662, -0.009371) and (t2[-1], p2[-1]) == (7.52047, 0.011364)
    assert np.all(np.diff(t1) > 0) and np.all(np.diff(t2) > 0)
    # the largest values: P1's second impact (t* 5.83) and P2's hump (t* 5.59)
    assert p1.max() == 0.87672 and t1[np.argmax(p1)] == 5.83288
    assert p2.max() == 0.235722 and t2[np.argmax(p2)] == 5.59126
    # and the first-impact windows lie inside the records (P1's starts at t* 2.0, 0.025 before its
    # first sample: the measure holds that sample's -0.018 over the gap, 0.05 % of the impulse)
    for sensor, (lo, hi) in PRESSURE_WINDOWS.items():
        assert data[sensor][0][0] - 0.03 <= lo < hi <= data[sensor][0][-1]


def test_the_moving_average_keeps_constants_and_lines_and_smooths_noise():
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(0.5, 1.5, 400)) * 1e-4  # uneven steps, as an adaptive run samples
    assert np.allclose(moving_average(t, np.full_like(t, 3.0), 0.005), 3.0)
    line = 2.0 + 5.0 * t
    inner = (t > t[0] + 0.0025) & (t < t[-1] - 0.0025)
    assert np.allclose(moving_average(t, line, 0.005)[inner], line[inner])
    noise = np.sin(2 * np.pi * 2000.0 * t)  # 2 kHz: ten periods in a 5 ms window
    assert np.max(np.abs(moving_average(t, noise, 0.005)[inner])) < 0.05


def test_peak_and_impulse_of_a_triangle():
    t = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    p = np.array([0.0, 0.0, 2.0, 0.0, 0.0])
    peak, when, impulse = peak_and_impulse(t, p, 0.5, 3.5)
    assert (peak, when) == (2.0, 2.0) and impulse == pytest.approx(2.0)
    # a window that cuts the triangle integrates only its part
    assert peak_and_impulse(t, p, 2.0, 4.0)[2] == pytest.approx(1.0)


@pytest.mark.slow  # a validation case (a minute alone): the slow tier; the record, the filter and the window's integrals are tested above
def test_the_quick_case_runs_and_reports_honest_verdicts(tmp_path, capsys):
    # When the quick case runs (H / 40, 3,200 particles, about a minute on one thread)
    rc = main(["validate", "dam_break_pressure", "--quick", "--out", str(tmp_path)])
    # Then every metric line is honest: a finite relative error against the case's tolerance, its
    # verdict and the exit code following the values
    lines = validation_lines(capsys.readouterr().out, "dam_break_pressure", PRESSURE_TOLERANCE, rc)
    # and it prints peak and impulse, raw and filtered, at both sensors
    names = [line.split()[0] for line in lines]
    assert names == [f"dam_break_pressure.{s}_{m}_{f}_relative" for s in ("P1", "P2") for f in ("raw", "filtered")
                     for m in ("peak", "impulse")], names
    assert (tmp_path / "dam_break_pressure.png").stat().st_size > 10_000
