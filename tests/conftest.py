"""Shared helpers for the test suite."""
import math
import os
from pathlib import Path

# Under pytest-xdist (make test: WORKERS processes) the workers share the cores, and a parallel loop's
# OpenMP threads spin while they wait for a thread the other worker's process has descheduled: the
# quick dam-break validation took 74 s beside a busy core, 38 s with passive waits (31 s with one
# thread; 2026-12-05, 2 cores). So the workers' numba threads (and the peer processes they start,
# which inherit it) wait passively; set before anything imports numba. Results do not depend on it.
if int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0") or 0) > 1:
    os.environ.setdefault("OMP_WAIT_POLICY", "passive")

import pytest

from sphcore.scene import load_scene, scene_from_dict

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "configs"


def pytest_collection_modifyitems(session, config, items):
    """The CUDA tests run last. Their simulator parity compares against the CPU backend in two
    subprocesses, which on a clean clone would compile every CPU kernel of their scenes themselves:
    13 minutes of this 2-core machine's 42 cold, 6 once the rest of the suite has filled numba's cache
    (2026-12-03). Only the order changes; each test still stands alone. ``make test`` hands whole files
    to its workers (pytest-xdist --dist loadfile) in this order, so test_cuda.py is still handed out
    last and its module fixtures run once."""
    items.sort(key=lambda item: item.path.name == "test_cuda.py")  # stable: the order within each part holds


@pytest.fixture
def configs_dir() -> Path:
    return CONFIGS


def scene(name: str, *overrides: str):
    """Load configs/<name>.toml with --set style overrides."""
    return load_scene(CONFIGS / f"{name}.toml", list(overrides))


def scene_dict(**sections):
    """A scene from plain dicts (tests that build their own geometry)."""
    return scene_from_dict(sections)


def settled_pressure_profile(sim, until, x_range, y_range):
    """Run ``sim`` to time ``until`` and fit p(y) = slope y + intercept over the particles inside
    x_range x y_range; returns (slope, surface height = -intercept / slope)."""
    import numpy as np

    while sim.t < until:
        sim.step()
    sim.refresh()
    s = sim.state
    n = s.n_owned
    x, y, p = s.x[:n, 0], s.x[:n, 1], s.p[:n]
    inside = (x > x_range[0]) & (x < x_range[1]) & (y > y_range[0]) & (y < y_range[1])
    slope, intercept = np.polyfit(y[inside], p[inside], 1)
    return slope, -intercept / slope


def one_process_and_two_peers(sc, steps=40):
    """Run scene ``sc`` for ``steps`` steps in one process and on two in-process peers (split in x);
    assert that ids, x, v and rho are bitwise equal; return (the one Simulation, the cluster)."""
    import numpy as np

    from nodes.cluster import InProcessCluster
    from sphcore.solver import Simulation
    one = Simulation(sc, "f64")
    cluster = InProcessCluster(sc, 2, "f64", dims=(2, 1, 1))
    for _ in range(steps):
        one.step()
        cluster.step()
    ref, got = one.final_arrays(), cluster.final_arrays()
    assert np.array_equal(ref["id"], got["id"])
    for key in ("x", "v", "rho"):
        assert np.array_equal(ref[key], got[key]), key
    return one, cluster


def validation_lines(out: str, case: str, tolerance: float, rc: int) -> list[str]:
    """The metric lines ``sph validate CASE`` printed, after checking that each is honest: a finite,
    non-negative relative error, the case's tolerance, and PASS exactly where the value is within it,
    and that the exit code is 1 exactly when one fails."""
    lines = [line for line in out.splitlines() if line.startswith(f"{case}.")]
    values = [float(line.split()[1]) for line in lines]
    verdicts = [line.split()[3] for line in lines]
    assert lines and all(math.isfinite(v) and v >= 0.0 for v in values), lines
    assert all(float(line.split()[2]) == tolerance for line in lines), lines
    assert verdicts == ["PASS" if v <= tolerance else "FAIL" for v in values], lines
    assert rc == (0 if all(v == "PASS" for v in verdicts) else 1)
    return lines
