"""Shared helpers for the test suite."""
from pathlib import Path

import pytest

from sphcore.scene import load_scene, scene_from_dict

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "configs"


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
