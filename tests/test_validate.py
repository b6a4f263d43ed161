"""sph validate: one line per metric with its tolerance and verdict, a plot per case, the exit code
follows the verdicts, and bad case names are refused."""
import numpy as np
import pytest

from launch.cli import main
from launch.validate import (CONFIGS, MARTIN_MOYCE_T, MARTIN_MOYCE_Z, Metric, _maxima, drop_semi_axes,
                             run_validate)


def test_metric_verdicts():
    assert Metric("a", 0.01, 0.05).passed and not Metric("b", 0.06, 0.05).passed
    assert not Metric("c", float("nan"), 0.05).passed
    assert Metric("d", 0.06, 0.05).line().split()[-1] == "FAIL"


def test_martin_moyce_data_is_the_digitized_table():
    assert len(MARTIN_MOYCE_T) == len(MARTIN_MOYCE_Z) == 15
    assert MARTIN_MOYCE_T[0] == 0.832 and MARTIN_MOYCE_Z[-1] == 13.970


def test_a_case_prints_its_metrics_writes_its_plot_and_sets_the_exit_code(tmp_path, capsys):
    rc = run_validate(["dam_break"], quick=True, out=tmp_path)
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("dam_break.")]
    assert len(lines) == 1
    verdict = lines[0].split()[3]
    assert verdict in ("PASS", "FAIL") and rc == (0 if verdict == "PASS" else 1)
    assert (tmp_path / "dam_break.png").stat().st_size > 10_000


def test_unknown_cases_are_refused(capsys):
    assert main(["validate", "sloshing"]) == 2
    assert "choose from hydrostatic, dam_break, dam_break_3d, taylor_green, oscillating_drop" in capsys.readouterr().err


def test_drop_reference_reproduces_the_published_period():
    """Monaghan & Rafiee (2013) give a period of 4.567375 s for omega = 1, A = 0.5; the largest
    semi-axis of that solution is sqrt(2) R."""
    t, a, b = drop_semi_axes(1.0, 0.5, 1.0, 10.0)
    peaks = _maxima(t, a)
    assert abs((peaks[1][0] - peaks[0][0]) - 4.567375) < 2e-4
    assert abs(peaks[0][1] - 2 ** 0.5) < 1e-6
    assert np.max(np.abs(a * b - 1.0)) < 1e-9  # area conserved: a b = R^2


def test_oscillating_drop_quick_meets_its_tolerances(tmp_path, capsys):
    rc = run_validate(["oscillating_drop"], quick=True, out=tmp_path)
    lines = [line.split() for line in capsys.readouterr().out.splitlines() if line.startswith("oscillating_drop.")]
    assert [line[0] for line in lines] == ["oscillating_drop.period_relative", "oscillating_drop.amplitude_relative"]
    assert all(line[3] == "PASS" for line in lines), lines
    assert rc == 0 and (tmp_path / "oscillating_drop.png").stat().st_size > 10_000


def test_central_force_pulls_towards_its_centre():
    """One particle at rest, 0.3 m from the centre, no gravity: after one symplectic Euler step
    v = -omega^2 (x - c) dt."""
    from sphcore.scene import load_scene
    from sphcore.solver import Simulation
    from sphcore.state import ParticleState
    scene = load_scene(CONFIGS / "oscillating_drop_2d.toml", ["forces.central_omega=2.0", "fluid.flow_rate=0.0",
                                                              "time.integrator='symplectic_euler'",
                                                              "time.mode='fixed'", "time.dt=1e-3"])
    sim = Simulation(scene, "f64")
    s = sim.state
    sim.state = ParticleState.create(s.id[:1], np.array([[0.3, -0.4, 0.0]]), np.zeros((1, 3)), s.m[:1], np.float64)
    sim.step()
    assert np.allclose(sim.state.v[0], [-4.0 * 0.3 * 1e-3, 4.0 * 0.4 * 1e-3, 0.0], rtol=1e-12, atol=0)
