"""Every shipped scene builds and runs a few steps: finite state, no leaks, the promised particle count."""
import numpy as np
import pytest

from sphcore.scene import load_scene
from sphcore.solver import Simulation

from conftest import CONFIGS

CONFIG_FILES = sorted(CONFIGS.glob("*.toml"))

# Particle counts the scenes promise in their header comments (about +-25 % around "~N").
PROMISED = {
    "dam_break": (30_000, 60_000),       # "About 49,000 particles"
    "dam_break_2d": (2_400, 4_000),      # "~3,200 particles"
    "dam_break_pressure_2d": (2_400, 4_000),  # "~3,200 particles"
    "dam_break_obstacle": (10_000, 16_700),  # "About 13,000 particles"
    "mesh_obstacle": (11_000, 17_000),   # "~14,000 particles"
    "hydrostatic_2d": (1_900, 3_100),    # "~2,500"
    "obstacle": (8_000, 13_000),         # "~10,400 particles"
    "taylor_green_2d": (7_500, 12_500),  # "10,000 particles"
    "oscillating_drop_2d": (3_800, 6_300),  # "~5,000 particles"
    "poiseuille_2d": (720, 1_200),       # "960 particles"
    "couette_2d": (720, 1_200),          # "960 particles"
    "floating_box_2d": (3_000, 5_000),   # "~4,000 particles"
    "floating_square_2d": (4_000, 6_000),  # "~5,000 particles"
    "settling_cylinder_2d": (3_300, 5_500),  # "~4,400 particles"
    "settling_cylinder_closed_2d": (3_500, 5_900),  # "~4,700 particles"
    "cavity_2d": (1_900, 3_100),         # "2,500 particles"
    "channel_2d": (1_800, 3_000),        # "2400 particles"
    "circular_couette_2d": (2_800, 4_700),  # "3,770 particles"
    "wave_maker_2d": (6_000, 10_000),    # "8,000 particles"
    "tiny": (100, 1_000),                # "Under 1,000 particles"
}


def test_every_config_has_a_promised_particle_range():
    assert {p.stem for p in CONFIG_FILES} == set(PROMISED)


@pytest.mark.parametrize("path", CONFIG_FILES, ids=[p.stem for p in CONFIG_FILES])
def test_config_runs_three_steps(path):
    # Given a shipped scene at its own resolution
    scene = load_scene(path)
    sim = Simulation(scene, "f64")
    s = sim.state
    # When it runs three steps
    for _ in range(3):
        sim.step()
    # Then time advanced, the state is finite, nothing leaked through a wall
    n = s.n_owned
    assert sim.step_index == 3 and sim.t > 0
    assert np.isfinite(s.x[:n]).all()
    assert np.isfinite(s.v[:n]).all()
    assert np.isfinite(s.rho[:n]).all() and (s.rho[:n] > 0).all()
    assert sim.leaks == 0
    assert n == sim.n_particles
    # and the particle count is what the scene's header promises
    lo, hi = PROMISED[path.stem]
    assert lo <= sim.n_particles <= hi, f"{path.stem}: {sim.n_particles} particles, promised {lo}-{hi}"
