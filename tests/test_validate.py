"""sph validate: one line per metric with its tolerance and verdict, a plot per case, the exit code
follows the verdicts, and bad case names are refused."""
import math
import re

import numpy as np
import pytest

from launch.cli import main
from launch.validate import (CONFIGS, MARTIN_MOYCE_T, MARTIN_MOYCE_Z, RELEASE_DELAY_MAX_T, Metric, _maxima, dam_break_scene,
                             drop_semi_axes, fit_release_delay, front_rms, front_speed, poiseuille_velocity, run_validate)


def test_metric_verdicts():
    assert Metric("a", 0.01, 0.05).passed and not Metric("b", 0.06, 0.05).passed
    assert not Metric("c", float("nan"), 0.05).passed
    assert Metric("d", 0.06, 0.05).line().split()[-1] == "FAIL"


def test_martin_moyce_data_is_the_digitized_table():
    assert len(MARTIN_MOYCE_T) == len(MARTIN_MOYCE_Z) == 15
    assert MARTIN_MOYCE_T[0] == 0.832 and MARTIN_MOYCE_Z[-1] == 13.970


def test_a_case_prints_its_metrics_writes_its_plot_and_sets_the_exit_code(tmp_path, capsys):
    rc = run_validate(["dam_break"], quick=True, out=tmp_path, orders=1)
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("dam_break.")]
    assert [line.split()[0] for line in lines] == ["dam_break.front_rms_shifted", "dam_break.front_speed_relative"]
    verdicts = [line.split()[3] for line in lines]
    assert set(verdicts) <= {"PASS", "FAIL"} and rc == (0 if verdicts == ["PASS", "PASS"] else 1)
    assert "15 points" in lines[0] and "the simulated clock + 0.175" in lines[0]  # the 3 m tank, the fixed shift
    assert (tmp_path / "dam_break.png").stat().st_size > 10_000
    assert not (tmp_path / "dam_break_orders.png").exists()  # once: no orders


def _front(times, delay):
    """A front that follows Martin & Moyce's points exactly, released ``delay`` earlier."""
    return np.interp(times + delay, MARTIN_MOYCE_T, MARTIN_MOYCE_Z, left=1.0)


def test_the_release_fit_recovers_a_known_delay_and_never_runs_the_experiment_early():
    times = np.linspace(0.0, 10.0, 5001)
    t, z = MARTIN_MOYCE_T[1:], MARTIN_MOYCE_Z[1:]
    for delay in (0.0, 0.137, 0.42):
        fronts = _front(times, delay)  # reaches each point `delay` early: a released-at-once front
        assert fit_release_delay(t, z, times, fronts) == pytest.approx(delay, abs=2e-3)
        assert front_rms(t, z, times, fronts, fit_release_delay(t, z, times, fronts)) < 1e-3
        assert delay == 0.0 or front_rms(t, z, times, fronts) > 0.02  # unshifted, the lead shows
    late = _front(times, -0.3)  # a front slower than the experiment: no release explains it
    assert fit_release_delay(t, z, times, late) == 0.0
    assert front_rms(t, z, times, late, 0.0) > 0.02
    fast = 1.0 + 1.2 * (_front(times, 0.0) - 1.0)  # runs 20 % too far: no delay makes up for a wrong speed
    assert front_rms(t, z, times, fast, fit_release_delay(t, z, times, fast)) > 0.05
    assert fit_release_delay(t, z, times, 1.0 + 3.0 * (_front(times, 0.0) - 1.0)) <= 2.0 * RELEASE_DELAY_MAX_T


@pytest.mark.parametrize("dim", [2, 3])
def test_the_dam_break_scene_lets_the_front_reach_every_measured_point(dim):
    # the 2D scene's probes once made the 3D case refuse to start (2-component points in 3D)
    sc = dam_break_scene(0.01, dim)
    assert sc.dim == dim and all(len(p.at) == 3 for p in sc.probes)
    a = sc.fluid.blocks[0].max[0]
    assert MARTIN_MOYCE_Z[-1] < (sc.domain.center[0] + 0.5 * sc.domain.size[0] - 2 * 0.01) / a


def test_the_front_speed_is_the_slope_between_the_late_points_whatever_the_shift():
    times = np.linspace(0.0, 10.0, 5001)
    exact = _front(times, 0.0)
    measured = (MARTIN_MOYCE_Z[13] - MARTIN_MOYCE_Z[8]) / (MARTIN_MOYCE_T[13] - MARTIN_MOYCE_T[8])
    assert front_speed(MARTIN_MOYCE_T, times, exact, 0.0) == pytest.approx(measured, rel=1e-3)
    # a front released 0.175 early is read at T - 0.175: the same front, the same speed
    assert front_speed(MARTIN_MOYCE_T, times, _front(times, 0.175)) == pytest.approx(measured, rel=1e-3)
    fast = 1.0 + 1.1 * (exact - 1.0)  # 10 % faster everywhere
    assert front_speed(MARTIN_MOYCE_T, times, fast, 0.0) == pytest.approx(1.1 * measured, rel=1e-3)


def test_the_help_names_every_case(capsys):
    from launch.validate import CASES
    with pytest.raises(SystemExit):
        main(["validate", "--help"])
    words = set(re.findall(r"[a-z0-9_]+", capsys.readouterr().out))
    assert set(CASES) <= words, set(CASES) - words


def test_unknown_cases_are_refused(capsys):
    assert main(["validate", "sloshing"]) == 2
    assert "choose from hydrostatic, hydrostatic_3d, dam_break, dam_break_3d, taylor_green, oscillating_drop, poiseuille, couette, floating_box, floating_square, settling_cylinder, settling_cylinder_closed, hydrostatic_probes" in capsys.readouterr().err


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


def test_poiseuille_series_starts_at_rest_and_ends_parabolic():
    y = np.linspace(0.0, 1e-3, 11)
    assert np.max(np.abs(poiseuille_velocity(y, 0.0, 2e-4, 1e-6, 1e-3))) < 1e-3 * 2.5e-5
    steady = 2e-4 / (2 * 1e-6) * y * (1e-3 - y)
    assert np.allclose(poiseuille_velocity(y, 50.0, 2e-4, 1e-6, 1e-3), steady, rtol=0, atol=1e-12)


def test_no_slip_walls_drag_a_uniform_flow_only_near_the_walls():
    """A uniform flow along the channel, no body force: the Morris viscosity exerts nothing in the
    bulk (no velocity differences) and drags every particle within a support of a plate."""
    from sphcore.scene import load_scene
    from sphcore.solver import Simulation
    from sphcore.state import ParticleState
    scene = load_scene(CONFIGS / "poiseuille_2d.toml", ["particles.spacing=5e-5", "forces.external=[0, 0]"])
    sim = Simulation(scene, "f64")
    s = sim.state
    v = np.zeros_like(s.v)
    v[:, 0] = 1e-5
    sim.state = ParticleState.create(s.id, s.x, v, s.m, np.float64)
    sim.refresh()
    s = sim.state
    n = s.n_owned
    d = np.minimum(s.x[:n, 1], 1e-3 - s.x[:n, 1])
    near = d + 0.5 * 5e-5 < sim.H  # the first virtual row behind the plate is within the support
    assert np.all(s.a[:n][near, 0] < 0.0)
    assert np.max(np.abs(s.a[:n][~near, 0])) < 1e-6 * np.max(np.abs(s.a[:n][near, 0]))
    inviscid = Simulation(load_scene(CONFIGS / "poiseuille_2d.toml", ["particles.spacing=5e-5",
                                                                     "forces.external=[0, 0]",
                                                                     "sph.viscosity='none'"]), "f64")
    s2 = inviscid.state
    inviscid.state = ParticleState.create(s2.id, s2.x, v, s2.m, np.float64)
    inviscid.refresh()
    assert np.max(np.abs(inviscid.state.a[:, 0])) < 1e-12  # free-slip without viscosity


@pytest.mark.slow
def test_poiseuille_quick_meets_its_tolerance(tmp_path, capsys):
    rc = run_validate(["poiseuille"], quick=True, out=tmp_path)
    line = [x.split() for x in capsys.readouterr().out.splitlines() if x.startswith("poiseuille.")][0]
    assert line[3] == "PASS" and rc == 0


@pytest.mark.slow
def test_hydrostatic_3d_quick_passes(tmp_path, capsys):
    """The same tank extruded 0.1 m between two walls (3,125 particles, 4 s: about a minute)."""
    assert main(["validate", "hydrostatic_3d", "--quick", "--out", str(tmp_path)]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("hydrostatic_3d.")]
    assert len(lines) == 4 and all(line.split()[3] == "PASS" for line in lines)
    assert (tmp_path / "hydrostatic_3d.png").stat().st_size > 0


def test_hydrostatic_quick_passes_and_set_overrides_reach_the_scene(tmp_path, capsys):
    # The shipped tank (carried density, delta-SPH) meets all four tolerances at quick resolution
    assert main(["validate", "hydrostatic", "--quick", "--out", str(tmp_path)]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("hydrostatic.")]
    assert len(lines) == 4 and all(line.split()[3] == "PASS" for line in lines)
    assert (tmp_path / "hydrostatic.png").stat().st_size > 0
    # With --set sph.density=summation the same case fails its single-particle metric (6.1 %, against
    # 0.21 % as shipped)
    assert main(["validate", "hydrostatic", "--quick", "--out", str(tmp_path), "--set", "sph.density=summation"]) == 1
    out = capsys.readouterr().out
    assert "scene overrides: sph.density=summation" in out
    single = [line for line in out.splitlines() if line.startswith("hydrostatic.pressure_error")][0]
    assert single.split()[3] == "FAIL" and float(single.split()[1]) > 0.03
    # The spacing belongs to the case
    assert main(["validate", "hydrostatic", "--set", "particles.spacing=0.05"]) == 2
    assert "each case sets its own spacing" in capsys.readouterr().err


@pytest.mark.fast
def test_faxens_series_matches_an_independent_finite_element_drag():
    """The settling cylinder's reference: Faxen's drag on a cylinder midway between two walls, against
    Taylor-Hood finite elements (scripts/investigations/faxen_fem_check.py, 2026-12-05: 21.9571 at
    k = 0.25 with elements of a / 20, 52.2905 at k = 0.4 with a / 10), and the unbounded limit's
    logarithm: the drag falls as the walls recede."""
    from launch.validate import faxen_drag
    assert faxen_drag(0.25) == pytest.approx(21.9571, rel=1e-3)
    assert faxen_drag(0.4) == pytest.approx(52.2905, rel=1e-2)
    assert faxen_drag(0.01) == pytest.approx(4.0 * math.pi / (math.log(100.0) - 0.9157), rel=1e-3)
    assert faxen_drag(0.1) < faxen_drag(0.2) < faxen_drag(0.3)


def _fake_case(calls, refuse=(), same_as_first=(), speeds=(1.0, 1.02, 1.06, 1.03, 1.01, 0.99, 1.04, 1.05)):
    """A stand-in for a case: its figures depend on how many orders ran before it; it refuses the
    orders in ``refuse`` like a scene would and reports the orders in ``same_as_first`` as resolving
    to the first one's sums."""
    from launch.validate import Metric, SceneError

    def case(quick, out, backend, opts):
        order = tuple(o for o in opts.overrides if o.startswith("run."))
        if order in refuse:
            raise SceneError(f"{' '.join(order) or 'the case'}: refused by this scene")
        k = len(calls)
        calls.append(opts.overrides)
        opts.check_order(0 if order in same_as_first else k)  # as _Clock does before the first step
        q = speeds[k]
        return [Metric("fake.error", 0.01 * (k + 1), 0.025, "e"),
                Metric("fake.speed", abs(q / 1.05 - 1.0), 0.03, "s", quantity=q, reference=1.05)]
    return case


def test_orders_give_each_metric_its_mean_and_spread_over_distinct_orders(tmp_path, capsys, monkeypatch):
    from launch import validate as V
    calls = []
    monkeypatch.setitem(V.CASES, "fake", _fake_case(calls, same_as_first={("run.cells_per_support=1",)}))
    rc = run_validate(["fake"], quick=True, out=tmp_path, overrides=("sph.alpha=0.02",), orders=3)
    lines = {line.split()[0]: line for line in capsys.readouterr().out.splitlines() if line.startswith("fake.")}
    # the case as configured, then the skin of 0; the cells of H resolved to the first order's sums here
    # (not counted), so the next order ran; the user's --set comes after each order's keys
    assert calls == [("sph.alpha=0.02",), ("run.neighbour_skin=0", "sph.alpha=0.02"),
                     ("run.cells_per_support=1", "sph.alpha=0.02"),
                     ("run.neighbour_skin=0", "run.cells_per_support=1", "sph.alpha=0.02")]
    error = lines["fake.error"].split()
    assert float(error[1]) == pytest.approx((0.01 + 0.02 + 0.04) / 3, rel=1e-3) and error[3] == "PASS"
    assert "the orders straddle the tolerance" in lines["fake.error"] and "each 0.01, 0.02, 0.04" in lines["fake.error"]
    # the relative metric compares the mean quantity (1.0, 1.02, 1.03), not the mean of the errors
    speed = lines["fake.speed"].split()
    assert float(speed[1]) == pytest.approx(abs((1.0 + 1.02 + 1.03) / 3 / 1.05 - 1.0), rel=1e-3)
    assert "against 1.05" in lines["fake.speed"] and speed[3] == "FAIL" and rc == 1  # 1.0167: 3.2 % under
    assert (tmp_path / "fake_orders.png").stat().st_size > 10_000


def test_a_mean_on_target_says_when_each_order_alone_misses(tmp_path, capsys, monkeypatch):
    from launch import validate as V
    monkeypatch.setitem(V.CASES, "fake", _fake_case([], speeds=(1.0, 1.1)))
    assert run_validate(["fake"], quick=True, out=tmp_path, orders=2) == 0  # speeds 1.0 and 1.1: mean 1.05
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("fake.speed"))
    assert float(line.split()[1]) == 0.0 and "each order alone misses the tolerance" in line


def test_orders_a_scene_refuses_are_left_out_and_said(tmp_path, capsys, monkeypatch, caplog):
    from launch import validate as V
    calls = []
    refused = {("run.neighbour_skin=0.1",), ("run.neighbour_skin=0.1", "run.cells_per_support=1")}
    monkeypatch.setitem(V.CASES, "fake", _fake_case(calls, refuse=refused))
    with caplog.at_level("INFO", logger="sph.validate"):
        run_validate(["fake"], quick=True, out=tmp_path, orders=8)
    assert len(calls) == 6  # 8 orders, 2 refused
    assert "6 orders of the sums (8 asked" in capsys.readouterr().out
    assert "6 of the 8 orders asked for ran" in caplog.text and "refused by this scene" in caplog.text
    assert "fake: order run.neighbour_skin=0.1 left out: run.neighbour_skin=0.1: refused by this scene" in caplog.text


def test_the_first_order_is_the_case_itself_and_its_errors_stand(tmp_path, monkeypatch):
    from launch import validate as V
    monkeypatch.setitem(V.CASES, "fake", _fake_case([], refuse={()}))
    with pytest.raises(V.SceneError):
        run_validate(["fake"], quick=True, out=tmp_path, orders=2)


def test_orders_refuse_a_set_of_the_keys_they_vary(tmp_path, capsys):
    assert main(["validate", "hydrostatic", "--orders", "2", "--set", "run.cells_per_support=1",
                 "--out", str(tmp_path)]) == 2
    assert ("hydrostatic runs in 2 orders of its sums (--orders), which vary run.neighbour_skin and "
            "run.cells_per_support themselves" in capsys.readouterr().err)
    assert main(["validate", "dam_break", "--set", "run.neighbour_skin=0", "--out", str(tmp_path)]) == 2
    assert "dam_break runs in 4 orders of its sums (--orders, its default)" in capsys.readouterr().err


def test_the_dam_break_runs_in_four_orders_that_differ_only_in_their_last_bits(tmp_path, capsys):
    # by default (CASE_ORDERS); the orders really change the rounding (the figures differ), and not the
    # model (they stay close)
    run_validate(["dam_break"], quick=True, out=tmp_path)
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("dam_break.front_speed_relative"))
    assert "the mean over 4 orders of the sums" in line
    each = [float(v) for v in re.search(r"each order's metric ([0-9.e-]+(?:, [0-9.e-]+)*)", line).group(1).split(", ")]
    assert len(each) == 4 and len(set(each)) > 1 and max(each) - min(each) < 0.05
    assert (tmp_path / "dam_break.png").exists() and (tmp_path / "dam_break_orders.png").exists()


def test_a_case_stops_before_stepping_when_its_sums_already_ran(monkeypatch):
    # on the GPU the automatic skin is 0: "as configured" and "skin 0" are the same sums; the case's
    # clock says so before a step is taken
    from launch import validate as V
    from sphcore.scene import grid_reach, list_skin, load_scene
    from sphcore.solver import Simulation
    scene = load_scene(CONFIGS / "hydrostatic_2d.toml", ["particles.spacing=0.05"])
    sim = Simulation(scene, "f64")
    resolved = (list_skin(scene, "cpu"), grid_reach(scene))
    V._Clock(sim, V.CaseOptions(), "x", 1.0)  # a first order: nothing ran before it
    with pytest.raises(V.RepeatedOrder, match="the same sums as skin 0 here"):
        V._Clock(sim, V.CaseOptions(orders_run={resolved: "skin 0"}), "x", 1.0)
    assert sim.step_index == 0
