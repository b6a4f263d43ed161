"""N peers (in-process transport) reproduce a single-process run bit for bit."""
import numpy as np
import pytest

from nodes.cluster import InProcessCluster
from sphcore.solver import Simulation

from conftest import scene


def run_single(sc, steps):
    sim = Simulation(sc, "f64")
    for _ in range(steps):
        sim.step()
    return sim.final_arrays()


@pytest.fixture(scope="module")
def dam_break_reference():
    sc = scene("dam_break", "particles.spacing=0.04")
    return run_single(sc, STEPS)


STEPS = 400


@pytest.mark.parametrize("dims, balance_every, balance_by", [
    ((2, 1, 1), 0, "particles"), ((2, 1, 1), 25, "particles"), ((3, 1, 1), 25, "particles"),
    ((4, 1, 1), 25, "particles"), ((2, 2, 1), 25, "particles"), ((3, 1, 1), 25, "time")])
def test_dam_break_n_peers_equal_one_peer_bitwise(dims, balance_every, balance_by, dam_break_reference):
    # Given the 3D dam break at a coarse spacing, run in one process and split over peers, with the
    # cut planes moved every 25 steps (load balancing) or fixed
    sc = scene("dam_break", "particles.spacing=0.04", f"decomposition.balance_every={balance_every}",
               f"decomposition.balance_by={balance_by}")
    reference = dam_break_reference
    cluster = InProcessCluster(sc, int(np.prod(dims)), "f64", dims=dims)
    for _ in range(STEPS):
        cluster.step()
    result = cluster.final_arrays()
    # Then ids are conserved (no particle lost or duplicated through migration) and every array is identical
    assert np.array_equal(result["id"], reference["id"])
    for key in ("x", "v", "rho"):
        assert np.array_equal(result[key], reference[key]), key
    assert sum(len(p.state.id[: p.state.n_owned]) for p in cluster.peers) == len(reference["id"])
    assert sum(h.migrated for h in cluster.halos) > 0  # particles did change owner on the way
    if balance_every:
        # and the balancer ran
        assert all(h.rebalances == STEPS // balance_every for h in cluster.halos)
        MOVED_CUTS[dims, balance_by] = cluster.halos[0].cut_moves


MOVED_CUTS = {}


def test_the_balancer_moved_cuts_in_the_runs_above():
    # (runs after the parametrized test in this module) the flow is fast enough to shift the cuts
    assert MOVED_CUTS and max(MOVED_CUTS.values()) > 0, MOVED_CUTS


@pytest.mark.fast
def test_optional_terms_across_peers_equal_one_peer_bitwise():
    # Given vorticity confinement (needs the ghosts' omega: a third exchange), XSPH, surface tension and
    # Balsara's switch (needs the ghosts' f: it travels with exchange 2)
    sc = scene("dam_break", "particles.spacing=0.05", "terms.vorticity_confinement=0.05", "terms.xsph=0.3",
               "terms.surface_tension=0.02", "sph.viscosity_switch='balsara'")
    reference = run_single(sc, 60)
    cluster = InProcessCluster(sc, 2, "f64", dims=(2, 1, 1))
    for _ in range(60):
        cluster.step()
    result = cluster.final_arrays()
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(result[key], reference[key]), key
    # and each peer computed part of its rows while exchanges 2 and 3 travelled, the rest after
    for h in cluster.halos:
        assert h.overlapped_rows > 0 and h.after_rows > 0, (h.overlapped_rows, h.after_rows)


@pytest.mark.fast
def test_in_process_network_delivers_by_receiver_sender_and_tag_and_detects_deadlock():
    from nodes.cluster import DeadlockError, _drive
    from nodes.transport import InProcessNetwork
    net = InProcessNetwork()
    a, b, c = net.endpoint(0), net.endpoint(1), net.endpoint(2)
    a.send(1, (0, "positions"), {"x": np.arange(3.0)})
    a.send(2, (0, "positions"), {"x": np.arange(5.0)})
    got = {}

    def receiver(end, key):
        got[key] = yield from end.recv(0, (0, "positions"))

    _drive([receiver(b, "b"), receiver(c, "c")])
    assert len(got["b"]["x"]) == 3 and len(got["c"]["x"]) == 5  # each peer gets its own message
    with pytest.raises(RuntimeError, match="sent twice"):
        a.send(1, (0, "fields"), {"x": np.zeros(1)})
        a.send(1, (0, "fields"), {"x": np.zeros(1)})
    with pytest.raises(DeadlockError):
        _drive([receiver(b, "never")], max_rounds=5)


@pytest.mark.fast
def test_balanced_cuts_are_the_best_cell_layer_cuts():
    from sphcore.decomposition import Decomposition
    rng = np.random.default_rng(3)
    for _ in range(50):
        hist = rng.integers(0, 100, size=12)
        dec = Decomposition.from_histograms((12, 4, 4), (2, 1, 1), [hist, np.ones(4), np.ones(4)], reach=1)
        cut = dec.cuts[0][1]
        best = min(range(2, 11), key=lambda c: abs(hist[:c].sum() - hist.sum() / 2))
        assert abs(hist[:cut].sum() - hist.sum() / 2) == abs(hist[:best].sum() - hist.sum() / 2)
        assert dec.cuts[1] == (0, 4) and dec.cuts[2] == (0, 4)


@pytest.mark.fast
def test_interior_rows_have_no_ghost_within_reach_and_overlap_off_gives_the_same_bits():
    # Given the 2D dam break over three peers side by side (the middle one has two neighbours), lists
    # built every step (exchange 1 in full; with a skin the cells are wider and the overlap is "moved")
    sc = scene("dam_break_2d", "particles.spacing=0.01", "run.neighbour_skin=0")
    cluster = InProcessCluster(sc, 3, "f64", dims=(3, 1, 1))
    for _ in range(5):
        cluster.step()
    for sim, halo in zip(cluster.peers, cluster.halos):
        # When a peer splits its owned rows (as sorted now) into interior and boundary rows
        interior, boundary = sim.engine.split_rows(halo.dec, halo.rank, halo.neighbours)
        n = sim.state.n_owned
        # Then together they are every owned row, once
        assert np.array_equal(np.sort(np.concatenate([interior, boundary])), np.arange(n))
        # and no interior row has a ghost (a row >= n_owned) among its neighbours, while boundary rows do
        grid = sim.grid
        nbr, counts = grid.nbr, grid.counts
        ghost_neighbours = np.array([(nbr[i, :counts[i]] >= n).sum() for i in range(n)])
        assert len(interior) and ghost_neighbours[interior].max() == 0
        assert len(boundary) and ghost_neighbours[boundary].max() > 0
    # And a run that waits for each exchange before computing gives the bits of one that overlaps
    overlapped = cluster.final_arrays()
    waiting = InProcessCluster(scene("dam_break_2d", "particles.spacing=0.01", "decomposition.overlap=false",
                                     "run.neighbour_skin=0"), 3, "f64", dims=(3, 1, 1))
    for _ in range(5):
        waiting.step()
    assert all(h.overlapped_rows == 0 for h in waiting.halos)
    # (the density ran on the interior rows while the ghosts' positions travelled, the accelerations
    # while their density did)
    assert all(h.overlapped_by_phase["positions"] > 0 and h.overlapped_by_phase["fields"] > 0 for h in cluster.halos)
    result = waiting.final_arrays()
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(result[key], overlapped[key]), key


@pytest.mark.fast
def test_lists_are_built_once_a_step_in_one_process_and_in_two_parts_on_a_peer(monkeypatch):
    # Given a count of the neighbour-list builds
    from sphcore.grid import Grid
    builds = []
    build = Grid.build_neighbours

    def counted(self, x, n_query, rows=None):
        builds.append("all" if rows is None else "rows")
        return build(self, x, n_query, rows)

    monkeypatch.setattr(Grid, "build_neighbours", counted)
    sc = scene("dam_break_2d", "particles.spacing=0.02", "run.neighbour_skin=0")  # no reused lists
    # When one process steps twice: one build of every row a step
    sim = Simulation(sc, "f64")
    builds.clear()
    sim.step()
    sim.step()
    assert builds == ["all", "all"]
    # and when two peers step once: each builds its interior rows' lists, then its boundary rows'
    cluster = InProcessCluster(sc, 2, "f64", dims=(2, 1, 1))
    builds.clear()
    cluster.step()
    assert builds == ["rows"] * 4
