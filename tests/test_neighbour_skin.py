"""run.neighbour_skin: Verlet lists built out to H (1 + skin), filtered to H every step and built
anew once a particle has moved part of the skin (sphcore/grid.py)."""
import json
from pathlib import Path

import numpy as np
import pytest

from launch.cli import main
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


def run_and_check_lists(config, sets, steps, every):
    """Run ``steps`` steps with a skin; every ``every`` steps bin once more and compare every row's
    filtered list with the brute-force neighbours of the positions now. Returns the simulation."""
    sim = Simulation(load_scene(config, sets), "f32")
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
    # Given the doubly periodic Taylor-Green vortex, whose particles cross the periodic edges
    sets = ["run.neighbour_skin=0.05"]
    assert Simulation(load_scene(TAYLOR_GREEN, sets), "f32").grid.periodic
    sim = run_and_check_lists(TAYLOR_GREEN, sets, 300, 50)
    assert sim.grid.reuses > 0


def test_filtered_lists_are_the_neighbours_where_inlets_add_and_outlets_remove_rows():
    # Given the channel, whose inlet adds particles and whose outlet removes them (each a new state)
    sim = run_and_check_lists(CHANNEL, ["run.neighbour_skin=0.1"], 200, 25)
    assert sim.grid.builds > 1


def test_a_skin_changes_the_rounding_only():
    # Given the 2D dam break run 300 steps with lists built every step, with a skin, and with cells of H
    # (run.cells_per_support = 1: the same neighbours summed in another order, a pure change of rounding)
    runs = {}
    for name, sets in (("plain", []), ("skin", ["run.neighbour_skin=0.1"]), ("cells", ["run.cells_per_support=1"])):
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


@pytest.mark.fast
def test_a_skin_with_peers_is_refused_before_any_process_starts(tmp_path, capsys):
    code = main(["run", DAM_2D, "--set", "run.neighbour_skin=0.1", "--peers", "2", "--no-viewer", "--quiet",
                 "--steps", "2", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    assert "run.neighbour_skin = 0.1 reuses lists in one process only" in err
    assert not (tmp_path / "out").exists()


@pytest.mark.fast
def test_the_memory_estimate_counts_the_candidate_lists():
    plain = bytes_per_particle(load_scene(DAM))
    assert bytes_per_particle(load_scene(DAM, ["run.neighbour_skin=0.2"])) - plain > 4 * 64 * 1.2 ** 3
