"""sph bench's real-time figure (seed 001): about how many particles fit in one 16.67 ms step, per
backend, from the measured steps/s."""
import pytest

from launch.bench import FRAME_S, frame_budget


def case(n, steps_per_s, backend="cpu", threads=2, precision="f64"):
    return {"code": "sphfluid", "backend": backend, "device": "GPU 0" if backend == "cuda" else "cpu",
            "precision": precision, "threads": threads, "particles": n, "steps_per_s": steps_per_s,
            "particle_steps_per_s": n * steps_per_s}


@pytest.mark.fast
def test_the_figure_comes_from_the_case_nearest_a_16_67_ms_step_per_backend():
    results = [case(10_000, 200.0), case(40_000, 50.0), case(160_000, 10.0),  # 5, 20 and 100 ms per step
               case(1_000_000, 100.0, backend="cuda", threads=0),              # 10 ms per step: extrapolated
               {"code": "pysph", "precision": "f64", "threads": 2, "particles": 5, "steps_per_s": 1.0,
                "particle_steps_per_s": 5.0},                                 # another code: not ours
               dict(case(40_000, 70.0), peers=2)]                              # a peer run: not a backend figure
    cpu, gpu = frame_budget(results)
    assert cpu["backend"] == "cpu" and cpu["from_particles"] == 40_000 and cpu["measured"]
    assert cpu["particles"] == int(40_000 * 50.0 * FRAME_S) == 33_333
    assert gpu["backend"] == "cuda" and gpu["device"] == "GPU 0" and not gpu["measured"]
    assert gpu["particles"] == int(1_000_000 * 100.0 * FRAME_S)


@pytest.mark.fast
def test_bench_until_steps_each_solver_from_rest_to_the_end_time_and_compares_like_with_like(capsys):
    """sph bench --until: the clock runs from the end of the first step to exactly T, DFSPH runs at the
    reference code's tolerances and reports its iterations, and the ratio pairs the same dx and threads."""
    from launch.bench import (DEFAULT_SCENE, DFSPH_DENSITY_TOLERANCE, _print_skin_ratios, _print_until_ratios,
                              _until_overrides, bench_until_case, spacing_for)
    dx = spacing_for(DEFAULT_SCENE, 600)
    assert f"sph.density_tolerance={DFSPH_DENSITY_TOLERANCE!r}" in _until_overrides(DEFAULT_SCENE, dx, "dfsph")
    assert not any("tolerance" in kv for kv in _until_overrides(DEFAULT_SCENE, dx, "wcsph"))
    until = 0.02
    runs = {solver: bench_until_case(DEFAULT_SCENE, dx, "f64", 1, solver, until) for solver in ("wcsph", "dfsph")}
    for solver, r in runs.items():
        assert r["method"] == solver and r["steps"] > 0 and r["wall_s"] > 0.0
        first_t = until - r["simulated_s"]
        assert 0.0 < first_t < until and r["mean_dt"] == pytest.approx(r["simulated_s"] / r["steps"])
        assert r["sim_s_per_wall_s"] == pytest.approx(r["simulated_s"] / r["wall_s"])
    assert runs["wcsph"]["solves"] == {}
    dens = runs["dfsph"]["solves"]["density"]
    assert dens["iterations_per_step"] >= 1.0 and dens["unconverged_steps"] == 0
    # DFSPH steps on the flow speed, WCSPH on the sound speed: far fewer steps to the same time
    assert runs["dfsph"]["steps"] * 5 < runs["wcsph"]["steps"]
    theirs = {"code": "splishsplash", "method": "dfsph", "threads": 1, "dx": dx, "particles": 600, "steps": 7,
              "sim_s_per_wall_s": runs["dfsph"]["sim_s_per_wall_s"] / 2.0, "viscosity": 8.6e-4,
              "viscosity_basis": "matched"}
    before = dict(theirs, sim_s_per_wall_s=runs["dfsph"]["sim_s_per_wall_s"] / 1.25, viscosity=0.01,
                  viscosity_basis="as before")
    _print_until_ratios([runs["dfsph"], dict(runs["dfsph"], dx=2 * dx), theirs, before])
    out = capsys.readouterr().out
    assert out.count("vs splishsplash dfsph") == 2, out
    assert "its viscosity 0.00086 m^2/s (matched): 2.00x" in out and "its viscosity 0.01 m^2/s (as before): 1.25x" in out
    # --skins: DFSPH reuses its lists with its automatic skin, and a list a step is timed beside it
    assert runs["dfsph"]["neighbour_skin"] == 0.45 and runs["dfsph"]["list_builds"] < runs["dfsph"]["steps"]
    plain = bench_until_case(DEFAULT_SCENE, dx, "f64", 1, "dfsph", until, skin=0.0)
    assert plain["neighbour_skin"] == 0.0 and plain["list_builds"] == plain["steps"]
    _print_skin_ratios([runs["dfsph"], plain, runs["wcsph"]])
    out = capsys.readouterr().out
    ratio = runs["dfsph"]["sim_s_per_wall_s"] / plain["sim_s_per_wall_s"]
    assert out.count("skin=0.45:") == 1 and f"{ratio:.3f}x" in out and "wcsph" not in out, out


@pytest.mark.fast
def test_the_viscosity_another_code_is_given_is_the_one_the_scene_acts_with():
    """sph bench --until --external gives SPlisHSPlasH the kinematic viscosity of our scene's fluid: the
    artificial viscosity's alpha c0 h / (2 (dim + 2)) (sph.alpha_nu is that figure), sph.nu for the
    Morris and Mueller viscosities, none without."""
    from launch.bench import DEFAULT_SCENE
    from sphcore.scene import load_scene, shear_viscosity
    scene = load_scene(DEFAULT_SCENE, ["particles.spacing=0.0125"])
    h = 0.5 * scene.sph.support * 0.0125
    assert shear_viscosity(scene) == pytest.approx(scene.sph.alpha * scene.sph.sound_speed * h / 10.0)
    assert shear_viscosity(scene) == pytest.approx(8.625e-4)  # alpha 0.02, c0 30 m/s, support 2.3 dx, 3D
    held = load_scene(DEFAULT_SCENE, ["particles.spacing=0.0125", "sph.alpha_nu=3.0e-4"])
    assert shear_viscosity(held) == pytest.approx(3.0e-4)
    morris = load_scene(DEFAULT_SCENE, ["particles.spacing=0.0125", "sph.viscosity='morris'", "sph.nu=2.5e-5"])
    assert shear_viscosity(morris) == 2.5e-5
    assert shear_viscosity(load_scene(DEFAULT_SCENE, ["sph.viscosity='none'"])) == 0.0
