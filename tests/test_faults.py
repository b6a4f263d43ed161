"""Faults: a resumed run carries every per-particle array to the right particle; a lost peer is
restarted from the newest checkpoint with the same bits; a killed launcher takes its peers down; a
stopped peer ends the run in seconds; a checkpoint that cannot be written is skipped, never fatal."""
import errno
import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from launch import supervise
from launch.cli import main
from nodes.cluster import _drive
from nodes.peer import decomposition_for, take_block
from nodes.supervise import watch_stdin
from nodes.transport import InProcessNetwork
from sphcore import checkpoint
from sphcore.halo import PeerHalo
from sphcore.scene import load_scene
from sphcore.solver import Simulation
from sphcore.state import merge_by_id

from test_peers import Lines, sph  # one helper for every test that runs processes

ROOT = Path(__file__).resolve().parent.parent
DAM2D = str(ROOT / "configs" / "dam_break_2d.toml")
SMALL = ["--set", "particles.spacing=0.02", "--precision", "f64"]


def assert_same(a, b):
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(a[key], b[key]), key


# -- resuming on several peers: carried arrays follow their particles --------------------------------
def test_a_resume_on_two_peers_keeps_each_particles_carried_values(tmp_path):
    # Given a one-process run that carries a per-particle value (the continuity density; DFSPH's
    # kappa travels the same way), checkpointed at step 15, and the same run continued to step 30
    carried = "density"
    scene = load_scene(DAM2D, ["particles.spacing=0.02", "sph.density=continuity"])
    sim = Simulation(scene, "f64")
    for _ in range(15):
        sim.step()
    root = tmp_path / "checkpoints"
    part = checkpoint.write_part(root, sim.step_index, 0, sim)
    checkpoint.commit(root, sim.step_index, checkpoint.sim_info(sim), sim.scene.to_dict(), [part])
    for _ in range(15):
        sim.step()
    reference = sim.final_arrays()
    ckpt = checkpoint.load(root)
    assert np.any(ckpt.arrays["extra_" + carried] != ckpt.arrays["extra_" + carried][0])  # not all alike
    # When two in-process peers resume from the checkpoint (as run_peer does) and run to step 30
    sims = []
    for _ in range(2):
        peer = Simulation(scene, "f64")
        checkpoint.restore(peer, ckpt)
        sims.append(peer)
    dec = decomposition_for(scene, sims[0].grid, 2, sims[0].state.x)
    network, halos = InProcessNetwork(), []
    for rank, peer in enumerate(sims):
        take_block(peer, dec, rank)
        s = peer.state
        # Then every carried array has one row per particle, the checkpoint's value for its id
        row = np.searchsorted(ckpt.arrays["id"], s.id)
        for name, values in s.extra.items():
            assert values.shape[0] == s.n
            assert np.array_equal(values, ckpt.arrays["extra_" + name][row]), name
        halos.append(PeerHalo(dec, rank, network.endpoint(rank), scene.decomposition.balance_every,
                              scene.decomposition.balance_by))
    while sims[0].step_index < 30:
        _drive([peer.stages(halo) for peer, halo in zip(sims, halos)])
    _drive([peer.refresh_stages(halo) for peer, halo in zip(sims, halos)])
    resumed = merge_by_id([peer.owned_arrays() for peer in sims], ("id", "x", "v", "rho"))
    # ... and the result is bitwise the uninterrupted run's
    assert_same(reference, resumed)


# -- the watch loop and the stdin watcher, with stand-in processes -------------------------------
def shell(script):
    return subprocess.Popen(["sh", "-c", script], **supervise.popen_options())


def test_watch_kills_a_stopped_process_at_once_and_a_silent_one_after_the_grace():
    # Given three "peers": one that fails with the peer-lost code, one stopped, one that never ends
    procs = [shell("sleep 0.3; exit 4"), shell("exec sleep 60"), shell("exec sleep 60")]
    os.kill(procs[1].pid, signal.SIGSTOP)
    t0 = time.monotonic()
    outcome = supervise.watch(procs, grace=1.0)
    elapsed = time.monotonic() - t0
    # Then the stopped one is the lost peer, the silent one was stopped after the grace, all in ~1 s
    assert outcome.code == 4 and outcome.lost.rank == 1 and outcome.lost.not_answering
    assert "stopped (SIGSTOP)" in outcome.lost.how
    assert all(p.poll() is not None for p in procs) and elapsed < 3.0, elapsed


@pytest.mark.parametrize("scripts, code, lost", [
    (["sleep 0.2; kill -9 $$", "sleep 0.5; exit 4"], 4, 0),    # killed by a signal: lost, restartable
    (["sleep 0.2; exit 3", "sleep 0.5; exit 4"], 3, None),     # the simulation failed: not restartable
    (["exit 0", "exit 0"], 0, None),
])
def test_watch_tells_a_lost_peer_from_a_failed_run(scripts, code, lost):
    outcome = supervise.watch([shell(s) for s in scripts], grace=2.0)
    assert outcome.code == code
    assert (outcome.lost.rank if outcome.lost else None) == lost


def test_supervisor_restarts_from_this_runs_newest_checkpoint_and_records_it(tmp_path):
    # Given an earlier run's checkpoint in the same folder, and attempts whose peer 1 dies twice
    root = tmp_path / "checkpoints"
    (root / "step_00000500").mkdir(parents=True)
    (root / "step_00000500" / "manifest.json").write_text('{"step": 500}')
    (root / "latest").write_text("step_00000500\n")
    calls = []

    def start(attempt, resume, history):
        calls.append((resume, len(history)))
        if len(calls) == 2:  # the second attempt commits a checkpoint of its own, then loses peer 1
            (root / "step_00000040").mkdir()
            (root / "step_00000040" / "manifest.json").write_text('{"step": 40}')
            (root / "latest").write_text("step_00000040\n")
        attempt.add(shell("sleep 0.2; exit 4"))
        attempt.add(shell("sleep 0.1; kill -9 $$"))
    supervisor = supervise.Supervisor(start, 2, root, grace=1.0)
    # When it runs
    code = supervisor.run()
    # Then the earlier run's checkpoint was never used, this run's was, and the run stops after 2
    assert code == 4
    assert calls == [(None, 0), (None, 1), (root / "step_00000040", 2)]
    first, second = supervisor.history
    assert (first["peer"], first["signal"], first["resumed_from_step"], first["checkpoint"]) == (1, 9, 0, None)
    assert (second["resumed_from_step"], second["checkpoint"]) == (40, str(root / "step_00000040"))


def test_watch_stdin_reads_after_a_first_line_taken_by_someone_else():
    # Given a pipe as stdin, whose first line (credentials) another reader has taken
    import io
    read_end, write_end = os.pipe()
    stream = io.TextIOWrapper(io.FileIO(read_end, "r"))
    os.write(write_end, b'{"name": "peer-0"}\nsomething else\n')
    assert stream.readline() == '{"name": "peer-0"}\n'
    ended = threading.Event()
    watch_stdin(ended.set, stream)
    # When the writer is gone, the watcher says so at once
    assert not ended.wait(0.3)
    os.close(write_end)
    assert ended.wait(2.0)


# -- processes -------------------------------------------------------------------------------------
CONTINUITY = ["--set", "sph.density=continuity"]  # carried per-particle values (state.extra) too
STEPS = "600"




class Pid(int):
    """A process id with the process's start time (clock ticks after boot), so that a later
    process or thread given the same id (ids are reused: pid_max is 32768 here) is not taken
    for it."""

    def __new__(cls, pid: int, start: int):
        self = super().__new__(cls, pid)
        self.start = start
        return self


def _stat(pid) -> list[str]:
    """/proc/PID/stat's fields from the state on (field 3 of proc(5) is index 0)."""
    return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()


def processes():
    """Pid -> (parent pid, argv) of every process of this machine."""
    out = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = _stat(entry.name)
                argv = [a.decode() for a in (entry / "cmdline").read_bytes().split(b"\0")]
            except OSError:
                continue
            out[Pid(int(entry.name), int(stat[19]))] = (int(stat[1]), argv)
    return out


def descendants(pid):
    table, found, todo = processes(), {}, [pid]
    while todo:
        parent = todo.pop()
        for child, (ppid, argv) in table.items():
            if ppid == parent and child not in found:
                found[child] = argv
                todo.append(child)
    return found


def peers_of(pid, exclude=()):
    """rank -> pid of the `sph peer` processes under launcher ``pid`` (not those in ``exclude``)."""
    return {int(argv[argv.index("--rank") + 1]): p for p, argv in descendants(pid).items()
            if "peer" in argv and "--rank" in argv and p not in exclude}


def wait_peers(pid, n, exclude=(), timeout=60):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = peers_of(pid, exclude)
        if len(found) == n:
            return found
        time.sleep(0.05)
    raise AssertionError(f"{n} peers not started: {descendants(pid)}")


def gone(pid: Pid) -> bool:
    """Whether process ``pid`` has exited (a zombie, or its id now names another process)."""
    try:
        stat = _stat(pid)
    except OSError:
        return True
    return stat[0] == "Z" or int(stat[19]) != pid.start


def wait_checkpoint(out, at_least, proc, timeout=120):
    """The step of OUT/checkpoints/latest once it is >= at_least."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            step = int((Path(out) / "checkpoints" / "latest").read_text().split("_")[1])
            if step >= at_least:
                return step
        except (OSError, ValueError, IndexError):
            pass
        time.sleep(0.01)
    raise AssertionError(f"no checkpoint >= {at_least} (launcher exit code {proc.poll()})")


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("one")
    assert main(["run", DAM2D, *SMALL, *CONTINUITY, "--steps", STEPS, "--no-viewer", "--quiet", "--out",
                 str(out)]) == 0
    return np.load(out / "final.npz")


@pytest.fixture
def launched():
    """Launchers started by a test; whatever is left of them is killed at the end."""
    started = []
    yield started
    for p in started:
        for pid in [p.pid, *descendants(p.pid)]:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def test_a_killed_and_a_stopped_peer_are_restarted_from_the_newest_checkpoint_with_the_same_bits(
        tmp_path, reference, launched):
    # Given a 2-peer run with checkpoints every 40 steps and two restarts allowed
    out = tmp_path / "o"
    p = sph("run", DAM2D, *SMALL, *CONTINUITY, "--steps", STEPS, "--no-viewer", "--out", out, "--peers", "2",
            "--checkpoint-every", "40", "--restarts", "2", "--timeout", "5", "--set", "run.log_every=500")
    launched.append(p)
    log = Lines(p.stderr)
    # When peer 1 is killed (kill -9) after the first checkpoint
    first = wait_checkpoint(out, 40, p)
    attempt1 = wait_peers(p.pid, 2)
    os.kill(attempt1[1], signal.SIGKILL)
    at_kill = wait_checkpoint(out, first, p)  # (on a loaded machine the run may have checkpointed again)
    # ... and peer 0 of the restarted run is stopped (SIGSTOP) once that run has checkpointed too
    attempt2 = wait_peers(p.pid, 2, exclude=attempt1.values())
    second = wait_checkpoint(out, at_kill + 40, p)
    t_stop = time.perf_counter()
    os.kill(attempt2[0], signal.SIGSTOP)
    rc = p.wait(timeout=240)
    err = log.text()
    print(f"SIGSTOP to restart: {log.first('(restart 2 of 2)') - t_stop:.1f} s")
    # Then the run restarted twice and ended with the uninterrupted run's bits
    assert rc == 0, err
    assert_same(reference, np.load(out / "final.npz"))
    assert "peer 1 was killed by signal 9 (SIGKILL)" in err
    summary = json.loads((out / "summary.json").read_text())
    killed, stopped = summary["restarts"]
    # the newest checkpoint when the launcher restarted: the one seen at the kill, or the next one if
    # both parts of it were written before the kill and rank 0 committed it after
    resumed = killed["resumed_from_step"]
    assert first <= resumed <= at_kill + 40 and resumed % 40 == 0, (first, at_kill, resumed)
    assert f"restarting from checkpoint step {resumed} (restart 1 of 2)" in err
    assert "peer 0 is stopped (SIGSTOP) and not answering" in err
    assert "(restart 2 of 2)" in err
    assert summary["steps"] == int(STEPS) and summary["peers"] == 2
    assert (killed["peer"], killed["signal"]) == (1, 9)
    assert killed["step"] >= resumed and 0 <= killed["wall_s_lost"] <= killed["attempt_wall_s"]
    assert (stopped["peer"], stopped["not_answering"], stopped["exit_code"]) == (0, True, None)
    assert stopped["resumed_from_step"] >= second and "stopped (SIGSTOP)" in stopped["how"]
    assert all(gone(pid) for pid in [*attempt1.values(), *attempt2.values()])


@pytest.mark.slow  # the default suite recovers a lost hosts-file peer in test_multihost (namespace hosts)
def test_a_lost_peer_of_a_hosts_file_run_is_restarted_on_its_host(tmp_path, reference, launched):
    # Given a 2-"host" run (this machine, through an ssh stand-in that exits 255 when the remote
    # command is killed by a signal, as ssh does) with checkpoints and one restart allowed
    from launch.local import free_ports
    p0, p1 = free_ports(2)
    hosts = tmp_path / "hosts.txt"
    hosts.write_text(f"127.0.0.1 {p0} 1\n127.0.0.1 {p1} 1\n")
    fake_ssh = tmp_path / "fake_ssh.py"
    fake_ssh.write_text("import subprocess, sys\nrc = subprocess.call(['bash', '-c', sys.argv[2]])\n"
                        "sys.exit(255 if rc < 0 else rc)\n")
    out = tmp_path / "o"
    p = sph("run", DAM2D, *SMALL, *CONTINUITY, "--steps", STEPS, "--out", out, "--hosts", hosts,
            "--ssh", f"{sys.executable} {fake_ssh}", "--remote-python", sys.executable, "--checkpoint-every", "40",
            "--restarts", "1", "--timeout", "10")
    launched.append(p)
    log = Lines(p.stderr)
    # When the peer of rank 1 is killed after the first checkpoint
    first = wait_checkpoint(out, 40, p)
    attempt1 = wait_peers(p.pid, 2)
    os.kill(attempt1[1], signal.SIGKILL)
    at_kill = wait_checkpoint(out, first, p)  # (a loaded machine may have checkpointed again meanwhile)
    rc = p.wait(timeout=180)
    err = log.text()
    # Then both ranks were started again on their hosts and ports, from the newest checkpoint, and the
    # result is the same
    assert rc == 0, err
    assert_same(reference, np.load(out / "final.npz"))
    (restart,) = json.loads((out / "summary.json").read_text())["restarts"]
    resumed = restart["resumed_from_step"]
    assert first <= resumed <= at_kill + 40 and resumed % 40 == 0, (first, at_kill, resumed)
    assert f"restarting from checkpoint step {resumed} (restart 1 of 1)" in err
    assert restart["peer"] == 1 and restart["exit_code"] == 255


def test_a_stopped_peer_ends_the_run_in_seconds_and_nothing_is_left(tmp_path, launched):
    # Given a 2-peer run that would take minutes, whose peers give up on a silent peer after 5 s
    p = sph("run", DAM2D, *SMALL, "--steps", "1000000", "--no-viewer", "--out", tmp_path / "o", "--peers", "2",
            "--timeout", "5", "--set", "run.log_every=200")
    launched.append(p)
    log = Lines(p.stderr)
    log.wait_for("peer 0 sph.run INFO step", timeout=120, proc=p)
    peers = wait_peers(p.pid, 2)
    # When peer 1 is stopped (SIGSTOP: its sockets stay open, it just never answers)
    t0 = time.perf_counter()
    os.kill(peers[1], signal.SIGSTOP)
    rc = p.wait(timeout=60)
    ended = time.perf_counter()
    err = log.text()
    # Then the launcher says which peer is not answering, and it and every peer are gone within 15 s
    assert rc == 4, err
    assert "peer 1 is stopped (SIGSTOP) and not answering; killing it" in err
    assert ended - t0 < 15.0, (ended - t0, err)
    assert ended - log.first("peer 0 exited with code 4") < 3.0, err  # the launcher's own part
    assert all(gone(pid) for pid in peers.values())
    print(f"SIGSTOP to launcher exit: {ended - t0:.1f} s")


def test_a_killed_launcher_takes_its_peers_and_viewer_down(tmp_path, launched):
    # Given a 2-peer run with its viewer (the default), stepping
    p = sph("run", DAM2D, *SMALL, "--steps", "1000000", "--out", tmp_path / "o", "--peers", "2",
            "--set", "run.log_every=200")
    launched.append(p)
    log = Lines(p.stderr)
    log.wait_for("peer 0 sph.run INFO step", timeout=120, proc=p)
    children = descendants(p.pid)
    assert sum("viewer" in argv for argv in children.values()) == 1 and len(peers_of(p.pid)) == 2
    # When the launcher is killed (kill -9: no chance to clean up)
    t0 = time.perf_counter()
    os.kill(p.pid, signal.SIGKILL)
    while not all(gone(pid) for pid in children) and time.perf_counter() - t0 < 10:
        time.sleep(0.02)
    elapsed = time.perf_counter() - t0
    # Then every process it started is gone within 2 s
    assert all(gone(pid) for pid in children), [argv for pid, argv in children.items() if not gone(pid)]
    assert elapsed < 2.0, elapsed
    print(f"killed launcher: its {len(children)} processes gone in {elapsed:.2f} s")


# -- checkpoints that cannot be written --------------------------------------------------------------
def full_disk_at(step):
    """A part writer that writes a little, then finds the disk full, at checkpoint ``step``."""
    real = checkpoint._write_npz

    def write(file, arrays):
        if f"step_{step:08d}" in file.name:
            file.write(b"half a part")
            raise OSError(errno.ENOSPC, "No space left on device")
        real(file, arrays)
    return write


@pytest.mark.parametrize("what", ["part", "manifest"])
def test_a_full_disk_skips_one_checkpoint_and_the_run_goes_on(tmp_path, monkeypatch, caplog, what):
    # Given a one-process run with checkpoints every 10 steps, whose disk is full at step 20
    if what == "part":
        monkeypatch.setattr(checkpoint, "_write_npz", full_disk_at(20))
    else:
        real = Path.write_text

        def write_text(self, text, *a, **kw):
            if self.name == ".manifest.json.tmp" and "step_00000020" in str(self.parent):
                real(self, text[:10])
                raise OSError(errno.ENOSPC, "No space left on device")
            return real(self, text, *a, **kw)
        monkeypatch.setattr(Path, "write_text", write_text)
    out = tmp_path / "o"
    caplog.set_level(logging.WARNING, logger="sph.run")
    # When it runs to step 40
    assert main(["run", DAM2D, *SMALL, "--steps", "40", "--checkpoint-every", "10", "--no-viewer", "--quiet",
                 "--out", str(out)]) == 0
    # Then one warning names the file, the space needed and free, and the last good checkpoint ...
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1, warnings
    name = "peer_0000.npz" if what == "part" else "manifest.json"
    assert f"checkpoint step 20: cannot write {out / 'checkpoints' / '.step_00000020.partial' / name}" in warnings[0]
    assert "No space left on device (needs ~" in warnings[0] and " free there)" in warnings[0]
    assert "the run goes on (last good checkpoint: step 10)" in warnings[0]
    # ... nothing half-written is left, the later checkpoints were written, and the summary counts it
    root = out / "checkpoints"
    assert sorted(p.name for p in root.iterdir()) == ["latest", "step_00000030", "step_00000040"]
    saved = json.loads((out / "summary.json").read_text())["checkpoints"]
    assert (saved["written"], saved["failed"], saved["last"]) == (3, 1, 40)
    assert saved["failures"][0]["step"] == 20


FAILING_PEER = """
import errno, sys
from sphcore import checkpoint
real = checkpoint._write_npz
def write(file, arrays):
    if "step_00000040" in file.name:
        file.write(b"half a part")
        raise OSError(errno.ENOSPC, "No space left on device")
    real(file, arrays)
checkpoint._write_npz = write
from launch.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_a_peers_failed_part_leaves_the_staging_folder_to_the_others(tmp_path, monkeypatch):
    # Given a step's staging folder that peer 0 has just made (its part not written yet)
    scene = load_scene(DAM2D, ["particles.spacing=0.02"])
    sim = Simulation(scene, "f64")
    root = tmp_path / "checkpoints"
    checkpoint.staging(root, 40).mkdir(parents=True)
    real = checkpoint._write_npz

    def full_disk(file, arrays):
        file.write(b"half a part")
        raise OSError(errno.ENOSPC, "No space left on device")
    # When peer 1's part fails (disk full)
    monkeypatch.setattr(checkpoint, "_write_npz", full_disk)
    with pytest.raises(checkpoint.CheckpointWriteError, match="No space left on device"):
        checkpoint.write_part(root, 40, 1, sim)
    # Then nothing of peer 1's part is left, the folder is, and peer 0 still writes its part into it
    # (the folder went with the failed part once, and peer 0's write failed with it: rank 0 discards it)
    assert sorted(p.name for p in checkpoint.staging(root, 40).iterdir()) == []
    monkeypatch.setattr(checkpoint, "_write_npz", real)
    entry = checkpoint.write_part(root, 40, 0, sim)
    assert entry["file"] == "peer_0000.npz"
    checkpoint.discard(root, 40)
    assert not checkpoint.staging(root, 40).exists()


def test_when_one_peers_part_fails_rank_0_commits_nothing_of_that_step(tmp_path):
    # Given two peers started by hand, peer 1's disk full at checkpoint step 40
    from launch.local import free_ports
    p0, p1 = free_ports(2)
    out = tmp_path / "o"
    common = [DAM2D, *SMALL, "--steps", "80", "--checkpoint-every", "20", "--run-id", "full-disk", "--world", "2",
              "--insecure", "--no-frames", "--quiet", "--timeout", "60", "--out", str(out)]
    peers = [subprocess.Popen([sys.executable, "-m", "launch.cli", "peer", *common, "--rank", "0", "--listen",
                               f"tcp/127.0.0.1:{p0}"], cwd=ROOT, stderr=subprocess.PIPE, text=True),
             subprocess.Popen([sys.executable, "-c", FAILING_PEER, "peer", *common, "--rank", "1", "--listen",
                               f"tcp/127.0.0.1:{p1}", "--connect", f"tcp/127.0.0.1:{p0}"], cwd=ROOT,
                              stderr=subprocess.PIPE, text=True)]
    errors = [p.communicate(timeout=180)[1] for p in peers]
    # Then the run ends normally; rank 0 said once that step 40 is not kept, and why
    assert [p.returncode for p in peers] == [0, 0], errors
    lines = [line for line in errors[0].splitlines() if "checkpoint step 40" in line]
    assert len(lines) == 1 and "WARNING peer 1: checkpoint step 40: cannot write" in lines[0], errors[0]
    assert "peer_0001.npz: No space left on device (needs ~" in lines[0]
    assert "last good checkpoint: step 20" in lines[0]
    # ... and no trace of step 40 is left: neither committed nor half-written
    root = out / "checkpoints"
    assert sorted(p.name for p in root.iterdir()) == ["latest", "step_00000060", "step_00000080"]
    saved = json.loads((out / "summary.json").read_text())["checkpoints"]
    assert (saved["written"], saved["failed"], saved["last"]) == (3, 1, 80)
