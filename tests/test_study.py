"""sph study: the plan of configurations, the Pareto front, and one real configuration through the
report and the plot."""
import math

from launch.study import BASE, DFSPH_TOLERANCES, KERNELS, overrides, pareto, plan, plot, report_markdown, run_config


def test_plan_varies_one_knob_at_a_time_around_the_baseline():
    configs = plan("oscillating_drop", quick=False)
    dxs = (0.1, 0.05, 0.025)
    assert len(configs) == len(dxs) * len(KERNELS) + len(dxs) + 2 * len(dxs) + len(dxs) * len(DFSPH_TOLERANCES)
    for c in configs:
        changed = [k for k in ("kernel", "precision", "cfl", "solver") if c[k] != BASE[k]]
        assert len(changed) <= 1, c
        assert (c["tolerance"] is not None) == (c["solver"] == "dfsph")
    assert {c["dx"] for c in configs} == set(dxs)


def test_pareto_front_keeps_only_undominated_points():
    points = [(1.0, 0.5), (2.0, 0.1), (3.0, 0.2), (0.5, 0.9), (2.0, 0.3), (float("nan"), 0.01)]
    assert pareto(points) == [3, 0, 1]  # sorted by cost; (3, 0.2) and (2, 0.3) are beaten by (2, 0.1)


def test_a_real_configuration_is_measured_and_reported(tmp_path):
    r64 = run_config("oscillating_drop", dict(BASE, dx=0.1))
    r32 = run_config("oscillating_drop", dict(BASE, dx=0.1, precision="f32"))
    for r in (r64, r32):
        assert r["outcome"] == "ok"
        assert 0 < r["error"] < 0.2 and r["particles"] > 200 and r["steps"] > 1000
        assert r["wall_s"] > 0 and math.isclose(r["sim_time"], 10.0, rel_tol=1e-3)
        assert r["wall_per_sim_s"] == r["wall_s"] / r["sim_time"]
    text = report_markdown([r64, r32], [], {"command": "sph study", "date": "today", "machine": "here"}, "p.png")
    assert "| wcsph | wendland_c2 | 0.1 | f32 | 0.25 |" in text
    work = r32["particles"] * r32["steps"] / r32["sim_time"] / 1e6
    assert f"| {work:.3g} |" in text  # the machine-independent cost: particle-steps per simulated second
    assert "- 20%: WCSPH, wendland_c2, dx=0.1" in text  # both are within 20 %: the cheaper one is named
    plot([r64, r32], tmp_path / "p.png")
    assert (tmp_path / "p.png").stat().st_size > 10_000


def test_the_solver_axis_runs_dfsph_with_its_tolerance_and_reports_its_iterations():
    # Given the quick plan's DFSPH configuration of the oscillating drop
    cfg = [c for c in plan("oscillating_drop", quick=True) if c["solver"] == "dfsph"]
    assert len(cfg) == 1 and cfg[0]["tolerance"] == DFSPH_TOLERANCES[0]
    # Its overrides select the solver, its tolerance and the symplectic Euler step (the scene uses leapfrog)
    assert {"sph.solver='dfsph'", "sph.density_tolerance=0.001", "time.integrator='symplectic_euler'"} <= set(
        overrides(cfg[0]))
    assert "sph.solver='wcsph'" in overrides(BASE)
    # When it is measured
    r = run_config("oscillating_drop", cfg[0])
    assert r["outcome"] == "ok" and 0 < r["error"] < 0.2
    density_its, divergence_its = r["iterations"]
    assert density_its >= 2 and divergence_its >= 1  # MIN_ITERATIONS per solve
    wcsph = run_config("oscillating_drop", dict(BASE, dx=cfg[0]["dx"]))
    assert wcsph["iterations"] is None
    assert r["steps"] * 5 < wcsph["steps"]  # the flow-speed step, not the acoustic one
    # Then the table names the solver and the iterations
    text = report_markdown([wcsph, r], [], {"command": "sph study", "date": "today", "machine": "here"}, "p.png")
    assert "| dfsph (tol 0.001) | wendland_c2 | 0.1 | f64 | 0.25 |" in text
    assert f"| {density_its:.1f}, {divergence_its:.1f} | ok |" in text
