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
