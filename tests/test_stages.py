"""The stage declarations (sphcore/stages.py): they agree with their row functions, the refresh runs
every force term the step runs, and a term added by declaration (linear drag) does its physics."""
import numpy as np
import pytest

from sphcore import stages
from sphcore.physics.integration import statistics_row
from sphcore.physics.xsph import xsph_row
from sphcore.scene import load_scene
from sphcore.solver import Simulation

TG = "configs/taylor_green_2d.toml"


def _by_id(sim, a):
    s = sim.state
    return a[: s.n_owned][np.argsort(s.id[: s.n_owned], kind="stable")]


def test_a_declaration_that_disagrees_with_its_row_fails_at_once():
    with pytest.raises(TypeError, match="writes 'omega'"):
        stages.Stage("xsph", xsph_row, writes=("omega",)).check()
    with pytest.raises(TypeError, match="reduction 'mean'"):
        stages.Stage("statistics", statistics_row, writes=(), reduce=("mean",)).check()

    def row(i, x, velocity_squared):  # a name no backend provides
        x[i, 0] = velocity_squared
    from numba import njit
    with pytest.raises(TypeError, match="'velocity_squared'"):
        stages.Stage("bad", njit(row), writes=("x",)).check()


def test_an_overlap_group_whose_stage_reads_an_earlier_ones_writes_fails_at_once():
    # the accelerations may split into interior and boundary rows: no stage reads what an earlier writes
    assert stages.ACCELERATIONS[0] is stages.FORCES
    # but vorticity writes omega, which confinement reads from the neighbours: not one group
    with pytest.raises(TypeError, match="confinement reads \\['omega'\\]"):
        stages.overlap_group(stages.VORTICITY, stages.CONFINEMENT)
    # and any stage reading a after the forces wrote it is refused (declarations do not say whose row it reads)
    with pytest.raises(TypeError, match="dfsph_kick reads \\['a'\\]"):
        stages.overlap_group(stages.FORCES, stages.DFSPH_KICK)


def test_every_stage_reads_and_writes_only_declared_names():
    known = set(stages.ARGUMENTS) | stages.SCRATCH_NAMES
    for s in stages.STAGES:
        assert set(s.arguments) <= known, s.name
        assert set(s.choices) <= set(stages.CHOICES), s.name
        assert set(s.reads) | set(s.writes) == set(s.arguments), s.name


def test_the_refresh_computes_the_acceleration_the_step_integrates():
    # Given a leapfrog run with surface tension and vorticity confinement (terms added to a after forces)
    sc = load_scene("configs/tiny.toml", ["time.integrator='leapfrog'", "terms.surface_tension=0.05",
                                          "terms.vorticity_confinement=0.01", "terms.drag=2.0"])
    sim = Simulation(sc, "f64")
    for _ in range(4):
        sim.step()
    # When outputs refresh the fields at the current positions (the leapfrog output velocity is
    # v + dt/2 a) and the next step then computes its acceleration at the same positions
    sim.refresh()
    a_refresh = _by_id(sim, sim.state.a).copy()
    seen = {}
    run = sim.engine.run

    def spy(stage, **values):
        if stage is stages.INTEGRATE:
            seen["a"] = _by_id(sim, sim.state.a).copy()
        return run(stage, **values)
    sim.engine.run = spy
    sim.step()
    # Then both have every term: the same accelerations, bit for bit
    assert np.array_equal(a_refresh, seen["a"])


def test_drag_damps_a_uniform_flow_geometrically():
    # Given a periodic box of fluid at rest density moving uniformly, no gravity, linear drag k
    k, dt, steps = 5.0, 1e-3, 20
    sc = load_scene(TG, ["particles.spacing=0.05", "fluid.initial_flow='none'", "sph.viscosity='none'",
                         "time.mode='fixed'", f"time.dt={dt}", "time.integrator='symplectic_euler'",
                         f"terms.drag={k}", "forces.gravity=[0.0, 0.0, 0.0]"])
    sim = Simulation(sc, "f64")
    s = sim.state
    s.v[:, 0] = 0.3
    s.v[:, 1] = -0.1
    # When it runs
    for _ in range(steps):
        sim.step()
    # Then symplectic Euler gives v_n = v_0 (1 - k dt)^n (the lattice's pressure forces cancel)
    decay = (1.0 - k * dt) ** steps
    v = sim.state.v[: sim.state.n_owned]
    assert np.allclose(v[:, 0], 0.3 * decay, rtol=1e-9, atol=1e-12)
    assert np.allclose(v[:, 1], -0.1 * decay, rtol=1e-9, atol=1e-12)
    assert "drag" in sim.timers.samples


def test_a_term_that_is_off_is_not_run():
    sim = Simulation(load_scene("configs/tiny.toml"), "f64")
    sim.step()
    assert not {"drag", "surface_tension"} & set(sim.timers.samples)
    assert sim.force_terms == ()


@pytest.mark.fast
@pytest.mark.parametrize("n", [0, 1, 255, 257, 1000])
def test_a_reduction_over_blocks_of_rows_equals_one_over_every_row(n):
    # the CPU drivers of the stages that are not neighbour passes reduce their rows in blocks
    # (generate.REDUCE_BLOCKS): the maxima and the count of bad rows equal a plain pass over the rows,
    # whatever n, on all rows or on a subset, with bad rows anywhere
    from sphcore.backends.generate import REDUCE_BLOCKS
    assert not stages.STATISTICS.neighbour_pass and REDUCE_BLOCKS == 256
    sim = Simulation(load_scene(TG, ["particles.spacing=0.01"]), "f64")
    s = sim.state
    assert s.n_owned >= 1000
    rng = np.random.default_rng(n)
    s.v[:] = rng.normal(size=s.v.shape)
    s.a[:] = rng.normal(size=s.a.shape)
    s.rho[:] = 1000.0 * (1.0 + 0.01 * rng.normal(size=s.rho.shape))
    bad = rng.choice(n, size=min(n, 3), replace=False) if n else np.empty(0, np.int64)
    s.v[bad, 0] = np.nan
    s.n_owned = n

    def expected(rows):
        good = np.setdiff1d(rows, bad)
        v2 = (s.v[good] ** 2).sum(axis=1)
        a2 = (s.a[good] ** 2).sum(axis=1)
        r = s.rho[good] / 1000.0 - 1.0
        return (max(0.0, v2.max(initial=0.0)), max(0.0, a2.max(initial=0.0)), max(0.0, r.max(initial=0.0)),
                len(rows) - len(good))

    def reduced(rows=None):
        return tuple(sim.engine.run(stages.STATISTICS, rows=rows, rho0=sim.prm.rho0))

    assert reduced() == pytest.approx(expected(np.arange(n)), rel=1e-12)
    subset = np.arange(0, n, 3, dtype=np.int64)
    assert reduced(subset) == pytest.approx(expected(subset), rel=1e-12)
