"""Steering a run in one process and on two in-process peers, through the run driver every run uses
(nodes/driver.py drive, nodes/peer.py Controls): every key declared live (sphcore/scene.py) changed
after step k ends bitwise equal to the run checkpointed at step k and resumed with that key set;
reset equals a new run of the same length; step N holds the run again N steps later; checkpoint
writes one of the step it is taken at, and resuming from it continues the run bit for bit.

The controller is scripted: each command is handed to rank 0's endpoint at its first poll once the
run has done the given steps (one command per poll; ``held`` ones only while the run is held), and
the test reads the step each was applied after from summary.json."""
import json
import time
import tomllib

import numpy as np
import pytest

from conftest import scene
from nodes.cluster import InProcessCluster
from nodes.driver import PeerRun, RunPlan, drive, run_blocking
from nodes.transport import InProcessNetwork
from sphcore import checkpoint
from sphcore.halo import NULL_HALO
from sphcore.scene import live_change, live_keys, scene_from_dict
from sphcore.solver import Simulation

STEPS = 16


def script_commands(endpoint, sim, script):
    """Make ``endpoint`` (rank 0's) hand out ``script`` [(after_step, text, held)] as a controller
    would send it, and poll without yielding (a held rank 0 needs no other peer to run)."""
    pending = [(i, step, text, held) for i, (step, text, held) in enumerate(script)]
    last = {"step": None, "idle": 0}

    def take_commands():
        step = sim.step_index
        was_held = last["step"] == step
        last["step"] = step
        if pending and pending[0][1] <= step and (was_held or not pending[0][3]):
            i, _, text, _ = pending.pop(0)
            last["idle"] = 0
            return [{"id": f"{i:08x}", "text": text}]
        last["idle"] += 1
        if pending and last["idle"] > 10_000:
            raise AssertionError(f"the run waits at step {step} for a command the script does not send: {pending}")
        return []

    def idle(seconds):
        time.sleep(0)
        return
        yield

    endpoint.take_commands, endpoint.idle = take_commands, idle
    return pending


def run_one(sc, out, steps=STEPS, script=(), checkpoint_every=None, resume=None, precision="f64"):
    """``sc`` in one process (peer 0 of 1) through the run driver; (summary, final.npz, acks)."""
    sim = Simulation(sc, precision)
    if resume is not None:
        checkpoint.restore(sim, resume)
    endpoint = InProcessNetwork().endpoint(0)
    pending = script_commands(endpoint, sim, script)
    peer = PeerRun(sim, sc, NULL_HALO, endpoint)
    summary = run_blocking(drive(peer, RunPlan(steps, out=out, checkpoint_every=checkpoint_every, progress=False)))
    assert not pending, f"never sent: {pending}"
    return summary, dict(np.load(out / "final.npz")), endpoint.acks


def run_two(sc, out, steps=STEPS, script=(), checkpoint_every=None):
    """``sc`` on two in-process peers (split in x) through the run driver; (summary, final.npz, acks)."""
    cluster = InProcessCluster(sc, 2, "f64", dims=(2, 1, 1))
    endpoint = cluster.endpoints[0]
    pending = script_commands(endpoint, cluster.peers[0], script)
    summary = cluster.run(RunPlan(steps, out=out, checkpoint_every=checkpoint_every, progress=False))
    assert not pending, f"never sent: {pending}"
    return summary, dict(np.load(out / "final.npz")), endpoint.acks


RUNS = {"one process": run_one, "two peers": run_two}


def assert_same(a, b):
    assert np.array_equal(a["id"], b["id"])
    for key in ("x", "v", "rho"):
        assert np.array_equal(a[key], b[key]), key


def resumed_with(sc, out, step, text, steps=STEPS):
    """The reference: ``sc`` run to ``step`` with a checkpoint there, then resumed from it with
    ``text`` (KEY=VALUE) set, to ``steps``; its final.npz and summary."""
    run_one(sc, out / "first", steps=step, checkpoint_every=step)
    ckpt = checkpoint.load(out / "first" / "checkpoints")
    assert ckpt.manifest["step"] == step
    _, changed = live_change(scene_from_dict(ckpt.manifest["scene"], source=sc.source), text)
    summary, final, _ = run_one(changed, out / "resumed", steps=steps, resume=ckpt)
    return final, summary


# (the scene's overrides that make the key matter, KEY=VALUE, whether the final state must differ)
TERMS = ("terms.xsph=0.1", "terms.shifting=1.0", "terms.surface_tension=0.01", "terms.vorticity_confinement=0.1",
         "terms.drag=0.5", "terms.wall_friction=1e-6")
DFSPH = ("sph.solver=dfsph",)
INTO_WALLS = ("fluid.blocks[0].velocity=[-3.0, -3.0, 0.0]",)  # the pool thrown at two walls: wall contacts
CASES = {
    "fluid.rest_density": ((), "fluid.rest_density=1005.0", True),
    "sph.density_tolerance": (DFSPH, "sph.density_tolerance=0.000001", True),
    "sph.divergence_tolerance": (DFSPH, "sph.divergence_tolerance=0.000001", True),
    "sph.max_iterations": (DFSPH + ("sph.density_tolerance=0.000001",), "sph.max_iterations=2", True),
    "sph.delta": (("sph.density=continuity",), "sph.delta=0.05", True),
    "sph.sound_speed": ((), "sph.sound_speed=25.0", True),
    "sph.clamp_negative_pressure": ((), "sph.clamp_negative_pressure=false", True),
    "sph.background_pressure": (("sph.clamp_negative_pressure=false",), "sph.background_pressure=500.0", True),
    "sph.alpha": ((), "sph.alpha=0.2", True),
    "sph.alpha_nu": ((), "sph.alpha_nu=0.01", True),
    "sph.nu": (("sph.viscosity=muller", "sph.nu=1e-5"), "sph.nu=1e-3", True),
    "terms.xsph": (TERMS, "terms.xsph=0.3", True),
    "terms.shifting": (TERMS, "terms.shifting=0.5", True),
    "terms.surface_tension": (TERMS, "terms.surface_tension=0.05", True),
    "terms.surface_threshold": (TERMS, "terms.surface_threshold=0.5", True),
    "terms.vorticity_confinement": (TERMS, "terms.vorticity_confinement=0.5", True),
    "terms.drag": (TERMS, "terms.drag=2.0", True),
    "terms.wall_friction": (TERMS, "terms.wall_friction=1e-3", True),
    "forces.gravity": ((), "forces.gravity=[1.0, -9.81, 0.0]", True),
    "forces.external": ((), "forces.external=[2.0, 0.0, 0.0]", True),
    "forces.ramp_time": ((), "forces.ramp_time=0.05", True),
    "forces.central_omega": (("forces.central_omega=1.0",), "forces.central_omega=3.0", True),
    "forces.central_center": (("forces.central_omega=3.0",), "forces.central_center=[0.0, 0.1, 0.0]", True),
    "time.mode": (("time.dt=2e-4",), "time.mode=fixed", True),
    "time.dt": (("time.dt=2e-4", "time.mode=fixed"), "time.dt=1e-4", True),
    "time.cfl": ((), "time.cfl=0.1", True),
    "boundary.restitution": (INTO_WALLS, "boundary.restitution=0.9", True),
    "boundary.friction": (INTO_WALLS, "boundary.friction=0.9", True),
    "boundary.gap": (INTO_WALLS, "boundary.gap=0.45", True),
    "run.max_density_ratio": ((), "run.max_density_ratio=2.5", False),  # a health limit: no effect unless hit
    # read by the run driver, not the step: no effect on the particles (test_the_driver_follows_...)
    "decomposition.balance_every": ((), "decomposition.balance_every=4", False),
    "decomposition.balance_by": ((), "decomposition.balance_by=particles", False),
    "output.checkpoint_every": ((), "output.checkpoint_every=50", False),
    "output.checkpoint_keep": ((), "output.checkpoint_keep=3", False),
    "output.vtk_every": ((), "output.vtk_every=50", False),
    "output.probes_every": ((), "output.probes_every=4", False),
}


UNCHANGED = {}  # scene overrides -> final.npz of the run without a command


@pytest.mark.fast
def test_every_live_key_has_a_case():
    assert sorted(CASES) == sorted(live_keys())


# a term switched on or off: a restart in place from the current state (Simulation.change_scene)
SWITCHES = {
    "terms.drag on": ((), "terms.drag=1.0", True),
    "terms.wall_friction on": ((), "terms.wall_friction=1e-4", True),
    "terms.xsph on": ((), "terms.xsph=0.2", True),
    "terms.vorticity_confinement on": ((), "terms.vorticity_confinement=0.2", True),
    "terms.surface_tension on": ((), "terms.surface_tension=0.05", True),
    "terms.shifting off": (TERMS, "terms.shifting=0.0", True),
    "terms.xsph off": (TERMS, "terms.xsph=0.0", True),
    "sph.delta off": (("sph.density=continuity",), "sph.delta=0.0", True),
}


@pytest.mark.parametrize("run", RUNS, ids=list(RUNS))
@pytest.mark.parametrize("key", list(CASES) + list(SWITCHES))
def test_a_key_set_during_the_run_equals_resuming_with_it_set(key, run, tmp_path):
    # Given a run whose controller sets KEY after a few steps
    base, text, effect = CASES[key] if key in CASES else SWITCHES[key]
    key = key.split()[0]
    sc = scene("tiny", *base)
    summary, final, acks = RUNS[run](sc, tmp_path / "controlled", script=[(5, f"set {text}", False)])
    # Then the command was accepted and applied after one step k, recorded in summary.json and scene.toml
    (ack,) = acks
    assert ack[1] == "accepted", ack
    k = ack[2]
    key_now = text.split("=", 1)[0]
    assert [c[0] for c in summary["controls"]] == [k] and summary["controls"][0][1].startswith(f"set {key_now} = ")
    _, wanted = live_change(sc, text)
    section, name = key.split(".")
    written = scene_from_dict(tomllib.loads((tmp_path / "controlled" / "scene.toml").read_text()))
    assert getattr(getattr(written, section), name) == getattr(getattr(wanted, section), name)
    # And the final state is bitwise the run checkpointed at step k and resumed with KEY set
    reference, _ = resumed_with(sc, tmp_path / "reference", k, text)
    assert_same(final, reference)
    if effect:  # and the change did something: the run without it ends elsewhere
        if base not in UNCHANGED:  # the same for every key of this scene
            UNCHANGED[base] = run_one(sc, tmp_path / "unchanged")[1]
        assert not np.array_equal(UNCHANGED[base]["x"], final["x"])


@pytest.mark.fast
@pytest.mark.parametrize("base", [(), ("sph.density=continuity",), ("sph.solver=dfsph",),
                                  ("time.integrator=leapfrog",)], ids=["wcsph", "continuity", "dfsph", "leapfrog"])
@pytest.mark.parametrize("run", RUNS, ids=list(RUNS))
def test_reset_equals_a_new_run_of_the_same_length(run, base, tmp_path):
    # Given a run that is reset after step k, with the external force changed before (the carried
    # density and DFSPH's kappa start cold again)
    sc = scene("tiny", *base)
    summary, final, acks = RUNS[run](sc, tmp_path / "reset", script=[(3, "set forces.external=[1.0, 0.0, 0.0]", False),
                                                                       (6, "reset", False)])
    assert [a[1] for a in acks] == ["accepted", "accepted"], acks
    k = acks[1][2]
    assert [c for c in summary["controls"]][1] == [k, "reset"]
    assert summary["steps"] == STEPS
    # Then it ends where a new run of the changed scene ends after the steps that followed the reset
    _, changed = live_change(sc, "forces.external=[1.0, 0.0, 0.0]")
    _, fresh, _ = run_one(changed, tmp_path / "fresh", steps=STEPS - k)
    assert_same(final, fresh)
    assert summary["sim_time"] == json.loads((tmp_path / "fresh" / "summary.json").read_text())["sim_time"]


@pytest.mark.fast
@pytest.mark.parametrize("run", RUNS, ids=list(RUNS))
def test_pause_step_n_resume_and_commands_while_held(run, tmp_path):
    # Given a run paused after step k; while held, a controller sets a key, asks for 3 more steps,
    # and, held again, writes a checkpoint, then resumes
    sc = scene("tiny")
    script = [(4, "pause", False), (4, "set sph.alpha=0.2", True), (4, "step 3", True),
              (4, "resume", False),  # sent while running: rejected
              (4, "checkpoint", True), (4, "resume", True)]
    summary, final, acks = RUNS[run](sc, tmp_path / "steered", script=script)
    # Then every command is answered: the pause at step k, what came while held at k, step 3 with
    # the step it holds at again, the early resume rejected, the checkpoint and resume at k + 3
    results = [(a[1], a[2]) for a in acks]
    k = results[0][1]
    assert results == [("accepted", k), ("accepted", k), ("accepted", k + 3), ("rejected", results[3][1]),
                       ("accepted", k + 3), ("accepted", k + 3)], acks
    assert "not paused" in acks[3][3]
    assert summary["controls"] == [[k, "pause"], [k, "set sph.alpha = 0.2"], [k + 3, "pause"], [k + 3, "checkpoint"]]
    assert summary["steps"] == STEPS
    # And the run ends as one that changed sph.alpha after step k without pausing
    reference, _ = resumed_with(sc, tmp_path / "reference", k, "sph.alpha=0.2")
    assert_same(final, reference)
    # And the checkpoint holds step k + 3, and continuing from it ends the same
    ckpt = checkpoint.load(tmp_path / "steered" / "checkpoints")
    assert ckpt.manifest["step"] == k + 3 and ckpt.manifest["scene"]["sph"]["alpha"] == 0.2
    _, again, _ = run_one(scene_from_dict(ckpt.manifest["scene"]), tmp_path / "again", resume=ckpt)
    assert_same(final, again)


@pytest.mark.fast
@pytest.mark.parametrize("run", RUNS, ids=list(RUNS))
def test_checkpoint_now_while_running_resumes_bitwise(run, tmp_path):
    sc = scene("tiny")
    summary, final, acks = RUNS[run](sc, tmp_path / "run", script=[(7, "checkpoint", False)])
    k = acks[0][2]
    assert acks[0][1] == "accepted" and summary["controls"] == [[k, "checkpoint"]]
    assert summary["checkpoints"]["written"] == 1 and summary["checkpoints"]["last"] == k
    ckpt = checkpoint.load(tmp_path / "run" / "checkpoints")
    assert ckpt.manifest["step"] == k
    _, again, _ = run_one(sc, tmp_path / "again", resume=ckpt)
    assert_same(final, again)


@pytest.mark.fast
@pytest.mark.parametrize("run", RUNS, ids=list(RUNS))
def test_refused_commands_name_the_reason_and_change_nothing(run, tmp_path):
    sc = scene("tiny")
    script = [(2, "set time.steps=5", False),            # the run's length
              (2, "set sph.kernel=cubic_spline", False),  # changes the compiled step
              (2, "set particles.spacing=0.01", False),   # the particle set
              (2, "set sph.alpha=-1", False),             # out of range
              (2, "set sph.alhpa=0.1", False),            # no such key
              (2, "step 0", False), (2, "jump", False), (2, "resume", False)]
    summary, final, acks = RUNS[run](sc, tmp_path / "run", script=script)
    reasons = [a[3] for a in acks]
    assert [a[1] for a in acks] == ["rejected"] * len(script), acks
    assert "time.steps" in reasons[0] and "the run's length" in reasons[0]
    assert "sph.kernel" in reasons[1] and "compiled step" in reasons[1]
    assert "particles.spacing" in reasons[2] and "particle set" in reasons[2]
    assert "sph.alpha = -1" in reasons[3] and "[0, 10]" in reasons[3]
    assert "sph.alhpa" in reasons[4] and "did you mean 'alpha'" in reasons[4]
    assert "step '0'" in reasons[5] and "unknown command" in reasons[6] and "not paused" in reasons[7]
    assert summary["controls"] == []
    _, plain, _ = run_one(sc, tmp_path / "plain")
    assert_same(final, plain)


@pytest.mark.fast
def test_what_a_held_peer_is_sent_is_checked_before_it_is_applied():
    from types import SimpleNamespace

    from nodes.peer import Controls
    from sphcore.halo import Reject, encode_commands
    sim = Simulation(scene("tiny"), "f64")
    peer1 = Controls(sim, SimpleNamespace(), InProcessNetwork().endpoint(1), None, rank=1, world=2)

    def held(commands, resume=0, **extra):
        raw = commands if isinstance(commands, np.ndarray) else encode_commands(commands)
        return dict({"control": raw, "resume": np.array([resume], dtype=np.uint8)}, **extra)

    good = held([{"op": "set", "key": "sph.alpha", "value": 0.1}, {"op": "checkpoint"}])
    peer1._hold_check(good)
    assert good["commands"][1] == {"op": "checkpoint"} and good["resume"] is False
    for bad in (held([{"op": "pause"}]),                                         # the run is held already
                held([{"op": "set", "key": "sph.kernel", "value": "muller"}]),  # not live
                held([{"op": "set", "key": "time.steps", "value": 5}]),         # the run's length
                held([{"op": "set", "key": "sph.alpha", "value": 1e9}]),        # out of range
                held([{"op": "reset"}], resume=2), held([], extra=np.zeros(1)),
                {"control": encode_commands([])},
                held(np.frombuffer(b"[[[[", np.uint8)), held(np.frombuffer(b"\xff\xfe", np.uint8)),
                held(np.zeros(3, np.float64)), held(np.zeros(70_000, np.uint8))):
        with pytest.raises(Reject):
            peer1._hold_check(bad)
    assert sim.scene.sph.alpha != 0.1  # checking applies nothing


@pytest.mark.fast
@pytest.mark.parametrize("run", RUNS, ids=list(RUNS))
def test_the_driver_follows_the_keys_it_reads_itself(run, tmp_path):
    # Given a run that, after a few steps, starts checkpointing every 4 steps keeping 3, writing VTK
    # files every 8 steps and (on peers) moving its cuts every 4 steps
    sc = scene("tiny")
    script = [(5, "set output.checkpoint_every=4", False), (5, "set output.checkpoint_keep=3", False),
              (5, "set output.vtk_every=8", False), (5, "set decomposition.balance_every=4", False)]
    summary, final, acks = RUNS[run](sc, tmp_path / "run", script=script)
    assert [a[1] for a in acks] == ["accepted"] * 4, acks
    # Then the checkpoints, VTK files and rebalances follow the new values from the step they were set at
    steps = sorted(int(d.name.split("_")[1]) for d in (tmp_path / "run" / "checkpoints").glob("step_*"))
    assert steps == [8, 12, 16] and summary["checkpoints"]["every"] == 4 and summary["checkpoints"]["written"] == 3
    vtk = sorted((tmp_path / "run" / "vtk").glob("particles_s*_p0000.vtp"))
    assert [int(p.name[11:19]) for p in vtk] == [8, 16]
    if run == "two peers":  # balancing opens a step (or the final refresh) whose steps done are a multiple of 4
        k = next(step for step, text in summary["controls"] if "balance_every" in text)
        due = len([s for s in range(k, STEPS + 1) if s % 4 == 0])
        assert due > 0 and all(p["rebalances"] == due for p in summary["per_peer"]), summary["per_peer"]
    # And the particles end as without any of it (balancing moves cuts, never the physics)
    _, plain, _ = run_one(sc, tmp_path / "plain")
    assert_same(final, plain)
