"""Carried arrays (sphcore/state.py CARRIED and state.extra) follow their particle everywhere:
``ParticleState.take``, the wire/checkpoint names, and resuming a DFSPH or continuity-density run on
2 and 3 peers == the uninterrupted run, bitwise (issue 18: take_block once filtered the named
fields but not state.extra, and the multi-peer resume test's scene carried no extras)."""
import numpy as np
import pytest

from nodes.cluster import InProcessCluster, _drive
from nodes.peer import decomposition_for, take_block
from nodes.transport import InProcessNetwork
from sphcore import checkpoint
from sphcore.halo import PeerHalo
from sphcore.solver import Simulation
from sphcore.state import CARRIED, FIELDS, ParticleState, carried_layout, merge_by_id

from conftest import scene

DFSPH = ("sph.solver='dfsph'", "time.dt=0.002")
CONTINUITY = ("sph.density='continuity'",)


def small_state(n=6, dtype=np.float64):
    """A state whose every field and extra differs per row (row i holds values made from i)."""
    rows = np.arange(n, dtype=dtype)
    s = ParticleState.create(np.arange(100, 100 + n), np.stack([rows, 2 * rows, 3 * rows], 1), -np.stack(
        [rows, rows, rows], 1), 1.0 + rows, dtype, extra={"kappa": 0.5 * rows, "density": 1000.0 + rows})
    s.a[:] = 7.0 * rows[:, None]
    s.rho[:] = 990.0 + rows
    s.p[:] = 10.0 * rows
    return s


# -- ParticleState.take and the carried names --------------------------------------------------------
@pytest.mark.parametrize("rows", [np.array([True, False, True, True, False, True]), np.array([5, 0, 3])],
                         ids=["mask", "index"])
def test_take_filters_every_field_and_every_extra_alike(rows):
    # Given a state with two carried extras
    s = small_state()
    # When rows are taken
    t = s.take(rows)
    # Then every field (derived ones included) and every extra holds the source's rows, in order
    expected_ids = s.id[rows]
    assert np.array_equal(t.id, expected_ids)
    assert t.n == t.n_owned == len(expected_ids)
    for name in FIELDS:
        assert np.array_equal(getattr(t, name), getattr(s, name)[rows]), name
        assert getattr(t, name).flags.c_contiguous, name
    assert set(t.extra) == {"kappa", "density"}
    for name, values in t.extra.items():
        assert np.array_equal(values, s.extra[name][rows]), name
        assert values.flags.c_contiguous, name
    # ... as copies: changing the taken state leaves the source alone
    t.extra["kappa"][:] = -1.0
    t.x[:] = -1.0
    assert np.all(s.extra["kappa"] >= 0.0) and np.all(s.x >= 0.0)


def test_carried_arrays_round_trip_under_the_wire_and_checkpoint_names():
    s = small_state()
    n = 4
    arrays = s.carried_arrays(n)
    # the names old checkpoints and peers use: id, x, v, m, then extra_<name>
    assert list(arrays) == ["id", "x", "v", "m", "extra_kappa", "extra_density"]
    assert {k: (a.shape, a.dtype) for k, a in arrays.items()} == carried_layout(n, s.dtype, s.extra)
    back = ParticleState.from_carried(arrays, s.dtype)
    assert back.n == back.n_owned == n
    for name in CARRIED:
        assert np.array_equal(getattr(back, name), getattr(s, name)[:n]), name
    for name in ("a", "rho", "p"):
        assert not getattr(back, name).any(), name  # derived: recomputed by the next step
    assert {k: a.tolist() for k, a in back.extra.items()} == {k: a[:n].tolist() for k, a in s.extra.items()}


def test_any_extra_array_follows_its_particle_through_sorting_migration_and_rebalancing():
    # Given two peers of a periodic vortex (particles cross the cut both ways), with an array in
    # state.extra that no solver uses: each particle's own id. Balancing by measured time moves the
    # cuts (by how much varies from run to run; the tracer must follow its particle either way)
    # (no skin: particles migrate every step; with one they move at builds only, test_neighbour_skin.py)
    sc = scene("taylor_green_2d", "particles.spacing=0.05", "decomposition.balance_every=4",
               "decomposition.balance_by='time'", "run.neighbour_skin=0")
    cluster = InProcessCluster(sc, 2, "f64", dims=(2, 1, 1))
    for sim in cluster.peers:
        sim.state.extra["tracer"] = sim.state.id.astype(np.float64)
    # When they run while particles migrate and the balancer runs
    for _ in range(30):
        cluster.step()
    # Then the tracer still equals the id on every row, ghosts included
    assert sum(h.migrated for h in cluster.halos) > 0 and all(h.rebalances == 7 for h in cluster.halos)
    for sim in cluster.peers:
        s = sim.state
        assert s.extra["tracer"].shape == s.id.shape
        assert np.array_equal(s.extra["tracer"], s.id.astype(np.float64))


# -- resuming on several peers == the uninterrupted run ---------------------------------------------
def run_steps(sims, halos, until):
    while sims[0].step_index < until:
        _drive([sim.stages(halo) for sim, halo in zip(sims, halos)])


def final_with_extras(sims, halos) -> dict:
    """id, x, v, rho and every carried extra of all particles, sorted by id (after a refresh)."""
    _drive([sim.refresh_stages(halo) for sim, halo in zip(sims, halos)])
    parts = []
    for sim in sims:
        s = sim.state
        part = sim.owned_arrays()
        part.update({"extra_" + k: a[: s.n_owned] for k, a in s.extra.items()})
        parts.append(part)
    return merge_by_id(parts, tuple(parts[0]))


def write_checkpoint(root, sims):
    """Each peer writes its part and rank 0 commits, as run_peer does."""
    step = sims[0].step_index
    parts = [checkpoint.write_part(root, step, rank, sim) for rank, sim in enumerate(sims)]
    checkpoint.commit(root, step, checkpoint.sim_info(sims[0]), sims[0].scene.to_dict(), parts)
    return checkpoint.load(root)


def resumed_peers(sc, ckpt, n_peers):
    """``n_peers`` in-process peers resumed from ``ckpt`` the way run_peer resumes."""
    network, sims, halos = InProcessNetwork(), [], []
    for rank in range(n_peers):
        sim = Simulation(sc, "f64")
        checkpoint.restore(sim, ckpt)
        dec = decomposition_for(sc, sim.grid, n_peers, sim.state.x)
        take_block(sim, dec, rank)
        sims.append(sim)
        halos.append(PeerHalo(dec, rank, network.endpoint(rank), sc.decomposition.balance_every,
                              sc.decomposition.balance_by))
    return sims, halos


# Each carried value once in the default suite (1 -> 2 peers for DFSPH's kappa, 2 -> 3 for the
# carried density); the other two pairings are the slow tier's (each ~30-60 s on 2 cores)
@pytest.mark.parametrize("overrides, carried, written_by, resumed_on", [
    pytest.param(DFSPH, "kappa", 1, 2, id="1-2-dfsph"),
    pytest.param(CONTINUITY, "density", 2, 3, id="2-3-continuity"),
    pytest.param(DFSPH, "kappa", 2, 3, id="2-3-dfsph", marks=pytest.mark.slow),
    pytest.param(CONTINUITY, "density", 1, 2, id="1-2-continuity", marks=pytest.mark.slow)])
def test_a_resume_on_peers_equals_the_uninterrupted_run_bitwise(tmp_path, overrides, carried, written_by,
                                                                resumed_on):
    # Given an uninterrupted one-process run of a scene that carries a per-particle value
    sc = scene("tiny", *overrides)
    halfway, end = 12, 24
    one = Simulation(sc, "f64")
    for _ in range(end):
        one.step()
    reference = one.final_arrays()
    s = one.state
    reference[carried] = s.extra[carried][np.argsort(s.id[: s.n_owned], kind="stable")]
    # ... and the same run checkpointed halfway by ``written_by`` peers
    if written_by == 1:
        writers = [Simulation(sc, "f64")]
        for _ in range(halfway):
            writers[0].step()
    else:
        cluster = InProcessCluster(sc, written_by, "f64")
        for _ in range(halfway):
            cluster.step()
        writers = cluster.peers
    ckpt = write_checkpoint(tmp_path / "checkpoints", writers)
    values = ckpt.arrays["extra_" + carried]
    assert np.unique(values).size > 1, "the carried values must tell particles apart"
    # When ``resumed_on`` peers resume from it and run to the end
    sims, halos = resumed_peers(sc, ckpt, resumed_on)
    assert all(0 < sim.state.n_owned < sim.n_particles for sim in sims)  # each holds a real block
    for sim in sims:
        s = sim.state
        assert np.array_equal(s.extra[carried], values[np.searchsorted(ckpt.arrays["id"], s.id)])
    run_steps(sims, halos, end)
    resumed = final_with_extras(sims, halos)
    # Then ids, x, v, rho and the carried value are bitwise the uninterrupted run's
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(reference[key], resumed[key]), key
    assert np.array_equal(reference[carried], resumed["extra_" + carried]), carried
