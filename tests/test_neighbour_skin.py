"""run.neighbour_skin: Verlet lists built out to H (1 + skin), filtered to H every step and built
anew once a particle has moved part of the skin (sphcore/grid.py)."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from launch.cli import main
from nodes.cluster import InProcessCluster
from sphcore.scene import SceneError, bytes_per_particle, load_scene
from sphcore.solver import Simulation

ROOT = Path(__file__).resolve().parent.parent
DAM_2D = str(ROOT / "configs" / "dam_break_2d.toml")
DAM = str(ROOT / "configs" / "dam_break.toml")
CHANNEL = str(ROOT / "configs" / "channel_2d.toml")
TAYLOR_GREEN = str(ROOT / "configs" / "taylor_green_2d.toml")


def exact_lists(x, H2, period):
    """Every row's neighbours within H as the builder computes a separation (float32 arithmetic in
    the same order, grid.minimum_image on periodic axes), by brute force: row i -> sorted rows j != i."""
    out = []
    for i in range(x.shape[0]):
        d = x[i] - x
        for axis, L in enumerate(period):
            if L > 0:
                half = L * x.dtype.type(0.5)
                d[:, axis] = np.where(d[:, axis] > half, d[:, axis] - L,
                                      np.where(d[:, axis] < -half, d[:, axis] + L, d[:, axis]))
        d2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]
        js = np.nonzero(d2 < H2)[0]
        out.append(js[js != i])
    return out


def run_and_check_lists(config, sets, steps, every, precision="f32"):
    """Run ``steps`` steps with a skin; every ``every`` steps bin once more and compare every row's
    filtered list with the brute-force neighbours of the positions now. Returns the simulation."""
    sim = Simulation(load_scene(config, sets), precision)
    for step in range(steps):
        sim.step()
        if step % every == 0:
            sim.engine.bin()
            s, g = sim.state, sim.grid
            want = exact_lists(s.x[:s.n_owned], g.H2, g.period)
            for i in range(s.n_owned):
                assert np.array_equal(np.sort(g.nbr[i, :g.counts[i]]), want[i]), (step, i)
    return sim


@pytest.mark.fast
def test_filtered_lists_are_the_neighbours_while_particles_move():
    # Given the 2D dam break collapsing, with a skin of 0.1 H
    sim = run_and_check_lists(DAM_2D, ["run.neighbour_skin=0.1", "particles.spacing=0.02"], 400, 20)
    # Then the lists were reused on most steps and built anew as particles moved
    assert sim.grid.builds >= 5 and sim.grid.reuses > 5 * sim.grid.builds


def test_filtered_lists_are_the_neighbours_across_periodic_axes():
    # Given the doubly periodic Taylor-Green vortex (coarse: the brute-force check is O(n^2) in Python),
    # whose rows near the edges have neighbours across them; in float64, whose drivers for this scene
    # other tests compile too (a cold suite compiles each choice of scene and precision once)
    sets = ["run.neighbour_skin=0.05", "particles.spacing=0.025"]
    sim = run_and_check_lists(TAYLOR_GREEN, sets, 300, 50, "f64")
    assert sim.grid.periodic
    assert sim.grid.reuses > 0


def test_filtered_lists_are_the_neighbours_where_inlets_add_and_outlets_remove_rows():
    # Given the channel, whose inlet adds particles and whose outlet removes them (each a new state)
    sim = run_and_check_lists(CHANNEL, ["run.neighbour_skin=0.1"], 200, 25)
    assert sim.grid.builds > 1


def test_a_skin_changes_the_rounding_only():
    # Given the 2D dam break run 300 steps with lists built every step, with a skin, and with cells of H
    # (run.cells_per_support = 1: the same neighbours summed in another order, a pure change of rounding)
    runs = {}
    for name, sets in (("plain", ["run.neighbour_skin=0"]), ("skin", ["run.neighbour_skin=0.1"]),
                       ("cells", ["run.neighbour_skin=0", "run.cells_per_support=1"])):
        sim = Simulation(load_scene(DAM_2D, sets), "f32")
        for _ in range(300):
            sim.step()
        runs[name] = sim.final_arrays()
    # Then the skin moves the particles no more than another order of the same sums does
    def apart(name):
        assert np.array_equal(runs["plain"]["id"], runs[name]["id"])
        return float(np.abs(runs["plain"]["x"] - runs[name]["x"]).max())
    skin, cells = apart("skin"), apart("cells")
    assert 0.0 < skin < 4.0 * cells, (skin, cells)


def test_resume_from_between_two_builds_equals_the_continuous_run(tmp_path):
    small = ["--set", "particles.spacing=0.05", "--set", "run.neighbour_skin=0.2", "--no-viewer", "--quiet"]
    # Given a continuous run, and one stopped at step 50 (its checkpoint between two list builds)
    assert main(["run", DAM, *small, "--steps", "90", "--out", str(tmp_path / "full")]) == 0
    assert main(["run", DAM, *small, "--steps", "50", "--checkpoint-every", "50", "--out", str(tmp_path / "a")]) == 0
    first = json.loads((tmp_path / "a" / "summary.json").read_text())["neighbours"]
    assert first["list_reuses"] > first["list_builds"] > 0
    # When it is resumed to step 90
    assert main(["run", "--resume", str(tmp_path / "a"), "--steps", "90", "--no-viewer", "--quiet",
                 "--out", str(tmp_path / "b")]) == 0
    # Then the result is bitwise the continuous run's: the resumed run sorted and listed its rows by the
    # saved reference positions, as the continuous run had them
    full, resumed = np.load(tmp_path / "full" / "final.npz"), np.load(tmp_path / "b" / "final.npz")
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(full[key], resumed[key]), key
    summary = json.loads((tmp_path / "full" / "summary.json").read_text())["neighbours"]
    assert summary["skin"] == 0.2 and summary["list_builds"] + summary["list_reuses"] >= 90  # + the final refresh


@pytest.mark.fast
@pytest.mark.parametrize("sets, backend, fragment", [
    (["run.neighbour_skin=0.1", "run.neighbours='walk'"], "cpu", "run.neighbours = 'lists'"),
    (["run.neighbour_skin=0.1"], "cuda", "CPU backend only"),
    (["run.neighbour_skin=1.5"], "cpu", "run.neighbour_skin"),
    (["run.neighbour_skin=-0.1"], "cpu", "run.neighbour_skin"),
])
def test_a_skin_where_it_cannot_work_is_refused(sets, backend, fragment):
    with pytest.raises(SceneError, match="run.neighbour_skin") as e:
        load_scene(DAM_2D, sets, backend=backend)
    assert fragment in str(e.value)


def test_n_peers_reuse_lists_on_the_same_steps_and_equal_one_process_bitwise():
    # Given the 3D dam break with a skin, its blocks rebalanced every 25 steps (a build each time)
    sc = load_scene(DAM, ["particles.spacing=0.04", "run.neighbour_skin=0.03", "decomposition.balance_every=25"])
    single = Simulation(sc, "f64")
    for _ in range(300):
        single.step()
    reference = single.final_arrays()
    assert single.grid.reuses > 2 * single.grid.builds
    for dims in ((2, 1, 1), (2, 2, 1)):
        # When it runs as peers
        cluster = InProcessCluster(sc, int(np.prod(dims)), "f64", dims=dims)
        for _ in range(300):
            cluster.step()
        result = cluster.final_arrays()
        # Then every peer built its lists on the single process's steps, particles changed owner at
        # the builds, and every array is the single process's, bit for bit
        assert all((p.grid.builds, p.grid.reuses) == (single.grid.builds, single.grid.reuses) for p in cluster.peers)
        assert sum(h.migrated for h in cluster.halos) > 0
        # also where a peer had sent exchange 1 with the decision and another peer's rows asked for a
        # build: the early messages were dropped unread, none counted as dropped, none left behind
        assert sum(h.moved_unused for h in cluster.halos) > 0
        assert all(h.transport.dropped == 0 for h in cluster.halos) and not cluster.network._mail
        for key in ("id", "x", "v", "rho"):
            assert np.array_equal(result[key], reference[key]), (dims, key)


def test_a_two_peer_checkpoint_between_builds_resumes_on_one_and_three_peers(tmp_path):
    small = ["--set", "particles.spacing=0.05", "--set", "run.neighbour_skin=0.2", "--no-viewer", "--quiet"]
    run = [sys.executable, "-m", "launch.cli", "run"]
    # Given a continuous single-process run and a 2-peer run checkpointed at step 50
    assert main(["run", DAM, *small, "--steps", "90", "--out", str(tmp_path / "full")]) == 0
    done = subprocess.run(run + [DAM, *small, "--peers", "2", "--steps", "50", "--checkpoint-every", "50",
                                 "--out", str(tmp_path / "a")], cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    lists = json.loads((tmp_path / "a" / "summary.json").read_text())["neighbours"]
    assert lists["list_reuses"] > lists["list_builds"] > 0
    full = np.load(tmp_path / "full" / "final.npz")
    for peers in (1, 3):
        # When it is resumed on 1 and on 3 peers
        out = tmp_path / f"b{peers}"
        done = subprocess.run(run + ["--resume", str(tmp_path / "a"), "--peers", str(peers), "--steps", "90",
                                     "--no-viewer", "--quiet", "--out", str(out)], cwd=ROOT, capture_output=True,
                              text=True)
        assert done.returncode == 0, done.stderr
        # Then each gives the continuous run's bits
        resumed = np.load(out / "final.npz")
        for key in ("id", "x", "v", "rho"):
            assert np.array_equal(full[key], resumed[key]), (peers, key)


@pytest.mark.fast
def test_the_memory_estimate_counts_the_candidate_lists():
    plain = bytes_per_particle(load_scene(DAM, ["run.neighbour_skin=0"]))
    assert bytes_per_particle(load_scene(DAM, ["run.neighbour_skin=0.2"])) - plain > 4 * 64 * 1.2 ** 3


@pytest.mark.fast
def test_peers_drop_forged_moved_ghosts_and_list_decisions_and_stay_bitwise_equal():
    # Given two in-process 2-peer clusters of the 2D dam break with a skin, one of them fed forged
    # messages ahead of the genuine ones on steps that reuse their lists
    sc = load_scene(DAM_2D, ["particles.spacing=0.01", "run.neighbour_skin=0.1"])
    calm = InProcessCluster(sc, 2, "f64", dims=(2, 1, 1))
    hit = InProcessCluster(sc, 2, "f64", dims=(2, 1, 1))
    expected = {0: {}, 1: {}}
    for step in range(12):
        calm.step()
        if 4 <= step <= 8:
            for dest in (0, 1):
                lo, hi = hit.halos[dest]._ghost_rows[1 - dest]
                rows = hit.peers[dest].engine.rows_of(("x", "v", "m"), np.arange(lo, hi))
                forged = {
                    "owner": dict(rows, x=rows["x"] + 0.5),      # a ghost far beyond the skin
                    "mass": dict(rows, m=-rows["m"]),
                    "not finite": dict(rows, v=np.full_like(rows["v"], np.nan)),
                    "count": {k: a[:-1] for k, a in rows.items()},
                }
                for reason, arrays in forged.items():
                    hit.network.deliver(dest, 1 - dest, (step, "moved"), arrays)
                    expected[dest][reason] = expected[dest].get(reason, 0) + 1
                hit.network.deliver(dest, 1 - dest, (step, "lists"), {"max": np.array([np.nan])})
                hit.network.deliver(dest, 1 - dest, (step, "lists"), {"max": np.zeros(2)})
                expected[dest]["not finite"] += 1
                expected[dest]["count"] += 1
        reuses = hit.peers[0].grid.reuses
        hit.step()
        if 4 <= step <= 8:
            assert hit.peers[0].grid.reuses == reuses + 1  # the forged "moved" messages were read
    # Then every forged message was rejected for what it is, and the result did not change
    for rank, halo in enumerate(hit.halos):
        assert halo.transport.drops == {str(1 - rank): expected[rank]}, (rank, halo.transport.drops)
    a, b = calm.final_arrays(), hit.final_arrays()
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(a[key], b[key]), key


@pytest.mark.fast
def test_an_early_exchange_1_of_a_step_that_builds_is_read_and_a_forged_one_counted():
    # Given the 3D dam break on two peers with a thin skin: on the steps where one peer's rows allowed
    # a reuse (it sent exchange 1 with the decision) but the other's asked for a build
    sc = load_scene(DAM, ["particles.spacing=0.04", "run.neighbour_skin=0.03"])
    calm = InProcessCluster(sc, 2, "f64", dims=(2, 1, 1))
    early = []  # (step, the rank that sent an exchange 1 the step did not use)
    for step in range(60):
        before = [h.moved_unused for h in calm.halos]
        calm.step()
        early += [(step, r) for r, h in enumerate(calm.halos) if h.moved_unused > before[r]]
    assert early and all(h.transport.dropped == 0 for h in calm.halos)
    # When forged copies of it come first, on another cluster
    hit = InProcessCluster(sc, 2, "f64", dims=(2, 1, 1))
    expected = {0: {}, 1: {}}
    for step in range(60):
        for _, sender in [e for e in early if e[0] == step]:
            dest = 1 - sender
            lo, hi = hit.halos[dest]._ghost_rows[sender]
            rows = hit.peers[dest].engine.rows_of(("x", "v", "m"), np.arange(lo, hi))
            for reason, arrays in {"owner": dict(rows, x=rows["x"] + 0.5), "mass": dict(rows, m=-rows["m"])}.items():
                hit.network.deliver(dest, sender, (step, "moved"), arrays)
                expected[dest][reason] = expected[dest].get(reason, 0) + 1
        hit.step()
    # Then the peers read every early message, rejected the forged ones for what they are, and
    # stepped to the same bits
    for rank, halo in enumerate(hit.halos):
        assert halo.transport.drops == ({str(1 - rank): expected[rank]} if expected[rank] else {}), rank
    assert not hit.network._mail
    a, b = calm.final_arrays(), hit.final_arrays()
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(a[key], b[key]), key


@pytest.mark.fast
def test_the_automatic_skin_reuses_lists_on_the_cpu_only_and_wider_for_dfsph():
    from sphcore.scene import AUTO_SKIN, list_skin
    wcsph, dfsph = load_scene(DAM), load_scene(DAM, ["sph.solver='dfsph'"])
    assert wcsph.run.neighbour_skin == -1.0  # the default is automatic
    assert list_skin(wcsph) == AUTO_SKIN["wcsph"] == 0.2
    assert list_skin(dfsph) == AUTO_SKIN["dfsph"] == 0.45  # its steps move particles farther
    assert list_skin(load_scene(DAM, ["sph.solver='dfsph'"], backend="cuda"), "cuda") == 0.0
    assert list_skin(load_scene(DAM, backend="cuda"), "cuda") == 0.0
    assert list_skin(load_scene(DAM, ["run.neighbours='walk'"])) == 0.0
    assert list_skin(load_scene(DAM, ["run.neighbour_skin=0.3", "sph.solver='dfsph'"])) == 0.3  # a set value wins
    with pytest.raises(SceneError, match="or -1 for auto"):
        load_scene(DAM, ["run.neighbour_skin=-0.5"])
    # a period that holds 3 H but not 3 H (1 + skin): no skin automatically, a set one is refused
    short = ["particles.spacing=0.0833333333"]  # the 1 m Taylor-Green box holds 3 H, just
    assert list_skin(load_scene(TAYLOR_GREEN, short)) == 0.0
    with pytest.raises(SceneError, match=r"lower the skin to 0\.000 or less"):
        load_scene(TAYLOR_GREEN, short + ["run.neighbour_skin=0.1"])


def test_the_interior_rows_run_while_moved_ghosts_travel_and_overlap_off_gives_the_same_bits():
    # Given the 3D dam break on two peers with a skin, computing while exchange 1 travels or waiting for it
    runs = {}
    for overlap in ("true", "false"):
        sc = load_scene(DAM, ["particles.spacing=0.04", "run.neighbour_skin=0.2", f"decomposition.overlap={overlap}"])
        cluster = InProcessCluster(sc, 2, "f64", dims=(2, 1, 1))
        for _ in range(40):
            cluster.step()
        runs[overlap] = (cluster, cluster.final_arrays())
    # Then the overlapping peers filtered and summed interior rows while the reused lists' ghosts
    # travelled, and both give the same bits
    assert all(h.overlapped_by_phase.get("moved", 0) > 0 for h in runs["true"][0].halos)
    assert all(h.overlapped_rows == 0 for h in runs["false"][0].halos)
    # (and listed and summed them before that, while the build decision travelled)
    assert all(p.rows_before_decision > 0 for p in runs["true"][0].peers)
    assert all(p.rows_before_decision == 0 for p in runs["false"][0].peers)
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(runs["true"][1][key], runs["false"][1][key]), key


@pytest.mark.slow  # 45 s: the default suite is at its time budget
@pytest.mark.parametrize("sets", [["sph.solver='dfsph'"], ["sph.density='continuity'", "terms.shifting=0.1"]],
                         ids=["dfsph", "continuity-shifting"])
def test_a_set_skin_keeps_two_peers_bitwise_with_dfsph_and_the_carried_density(sets):
    # Given the 2D dam break with a skin set by hand (DFSPH has none by default: its steps are long)
    sc = load_scene(DAM_2D, ["particles.spacing=0.01", "run.neighbour_skin=0.3", *sets])
    single = Simulation(sc, "f64")
    for _ in range(60):
        single.step()
    cluster = InProcessCluster(sc, 2, "f64", dims=(2, 1, 1))
    for _ in range(60):
        cluster.step()
    # Then the lists were reused, and two peers give the single process's bits
    assert single.grid.reuses > single.grid.builds > 0
    a, b = single.final_arrays(), cluster.final_arrays()
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(a[key], b[key]), key
