"""Health beyond the per-step checks (sphcore/health.py): unconverged DFSPH solves and the energy
watchdog reported in summary.json and the exit code, and decided alike by one process and by peers."""
import json

import pytest

from conftest import CONFIGS, scene
from launch.cli import EXIT_SIMULATION, main
from nodes.cluster import InProcessCluster
from nodes.driver import PeerRun, RunPlan, drive, run_blocking
from nodes.transport import InProcessNetwork
from sphcore.halo import NULL_HALO
from sphcore.health import _decade
from sphcore.solver import Simulation, SimulationError

TINY = str(CONFIGS / "tiny.toml")
UNCONVERGED = ("sph.solver=dfsph", "time.dt=0.01", "sph.max_iterations=1", "sph.density_tolerance=1e-6")
WATCHED = ("run.energy_check_every=5",)


def run_one(sc, out, steps):
    sim = Simulation(sc, "f64")
    peer = PeerRun(sim, sc, NULL_HALO, InProcessNetwork().endpoint(0))
    return run_blocking(drive(peer, RunPlan(steps, out=out, progress=False)))


def run_two(sc, out, steps):
    return InProcessCluster(sc, 2, "f64", dims=(2, 1, 1)).run(RunPlan(steps, out=out, progress=False))


@pytest.mark.fast
def test_unconverged_steps_are_logged_at_each_decade():
    assert [k for k in range(1, 2001) if _decade(k)] == [1, 10, 100, 1000]


def test_two_peers_measure_the_energy_exactly_as_one_process(tmp_path):
    # Given the tiny scene checked every 5 steps, in one process and on two peers
    sc = scene("tiny", *WATCHED)
    one = run_one(sc, tmp_path / "one", 20)
    two = run_two(sc, tmp_path / "two", 20)
    # Then the energies (integer sums over the peers) are the same bits
    assert one["health"]["energy"]["watchdog"] == "on" and one["health"]["energy"]["last_step"] == 20
    assert one["health"] == two["health"]


def test_two_peers_stop_on_an_unconverged_solve_at_the_same_step(tmp_path):
    sc = scene("tiny", *UNCONVERGED, "sph.on_unconverged=stop")
    with pytest.raises(SimulationError) as one:
        run_one(sc, tmp_path / "one", 5)
    with pytest.raises(SimulationError) as two:
        run_two(sc, tmp_path / "two", 5)
    assert str(one.value).startswith("step 0 ") and str(two.value).startswith("step 0 ")
    assert "the DFSPH density solve did not converge" in str(two.value)
    stopped = json.loads((tmp_path / "two" / "summary.json").read_text())
    assert stopped["status"] == "stopped" and stopped["stopped"] == str(two.value)


def test_a_stop_exits_3_and_summary_json_says_stopped(tmp_path, capsys):
    out = tmp_path / "run"
    sets = [a for k in UNCONVERGED + ("sph.on_unconverged=stop",) for a in ("--set", k)]
    code = main(["run", TINY, *sets, "--steps", "5", "--out", str(out), "--no-viewer", "--quiet"])
    assert code == EXIT_SIMULATION
    err = capsys.readouterr().err
    assert "sph run: simulation stopped: step 0 (t = 0 s): the DFSPH density solve did not converge" in err
    assert "Traceback" not in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "stopped" and "sph.on_unconverged = 'stop'" in summary["stopped"]
    assert not (out / "final.npz").exists()  # nothing of the half-done step is written


def test_warnings_are_counted_in_summary_json(tmp_path):
    out = tmp_path / "run"
    sets = [a for k in UNCONVERGED for a in ("--set", k)]
    assert main(["run", TINY, *sets, "--steps", "12", "--out", str(out), "--no-viewer", "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "complete"
    assert summary["solver"]["density"]["unconverged_steps"] == 12
    assert summary["health"]["warnings"] == {"unconverged": 2, "energy": 0}  # the 1st and the 10th
    assert summary["health"]["on_unconverged"] == "warn"


def test_a_reset_or_a_live_change_takes_a_new_energy_reference():
    sim = Simulation(scene("tiny", *WATCHED), "f64")
    for _ in range(6):
        sim.step()
    assert sim.health.energy["reference_step"] == 1
    sim.set_parameter("forces.gravity", (0.0, -5.0, 0.0))  # another potential: another reference
    sim.step()
    assert sim.health.energy["reference_step"] == 7
    sim.reset()  # the initial particles again, t = 0
    sim.step()
    assert sim.health.energy["reference_step"] == 8 and sim.health.energy["reference_t"] == sim.t
