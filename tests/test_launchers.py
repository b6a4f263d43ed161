"""Many-machine launchers, exercised on this machine: the hosts-file launcher (with an ssh stand-in
that runs the command locally) and the SLURM task script (with SLURM's variables set by hand)."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from launch.cli import main
from launch.hosts import read_hosts
from launch.local import free_ports

ROOT = Path(__file__).resolve().parent.parent
DAM = "configs/dam_break.toml"
SMALL = ["--set", "particles.spacing=0.05", "--precision", "f64", "--steps", "60"]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("one")
    assert main(["run", str(ROOT / DAM), *SMALL, "--out", str(out), "--quiet"]) == 0
    return np.load(out / "final.npz")


def assert_same(reference, out):
    got = np.load(out / "final.npz")
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(got[key], reference[key]), key


@pytest.mark.parametrize("text, fragment", [
    ("", "no hosts listed"),
    ("node1\n", "expected 'HOST PORT [THREADS]'"),
    ("node1 port\n", "must be integers"),
    ("node1 70000\n", "port must be 1..65535"),
    ("node1 7447 0\n", "threads >= 1"),
    ("node1 7447\nnode1 7447 # twice\n", "listed twice"),
])
def test_hosts_file_errors_name_the_line(tmp_path, text, fragment):
    path = tmp_path / "hosts.txt"
    path.write_text(text)
    with pytest.raises(ValueError, match=fragment.replace("[", r"\[").replace("]", r"\]").replace(".", r"\.")):
        read_hosts(path)


def test_hosts_file_launcher_runs_one_peer_per_line(tmp_path, reference):
    # Given a hosts file with two "hosts" (this machine) and an ssh stand-in that runs the command here
    p0, p1 = free_ports(2)
    (tmp_path / "hosts.txt").write_text(f"# host port threads\n127.0.0.1 {p0} 1\n127.0.0.1 {p1} 1  # second\n")
    fake_ssh = tmp_path / "fake_ssh.py"
    fake_ssh.write_text("import subprocess, sys\nsys.exit(subprocess.call(['bash', '-c', sys.argv[2]]))\n")
    out = tmp_path / "out"
    # When sph run --hosts starts the peers through it
    done = subprocess.run([sys.executable, "-m", "launch.cli", "run", DAM, *SMALL, "--hosts",
                           str(tmp_path / "hosts.txt"), "--ssh", f"{sys.executable} {fake_ssh}",
                           "--remote-python", sys.executable, "--listen-host", "127.0.0.1", "--out", str(out),
                           "--quiet"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    # Then rank 0 wrote the same result as one process
    assert done.returncode == 0, done.stderr
    assert_same(reference, out)


def test_slurm_task_script_computes_every_endpoint(tmp_path, reference):
    # Given three SLURM tasks on one node (SLURM's variables set by hand) and the job's credentials
    base = free_ports(1)[0]
    out = tmp_path / "out"
    tls = tmp_path / "tls"
    assert main(["certs", str(tls), "--peer-host", "127.0.0.1", "--peer-host", "127.0.0.1",
                 "--peer-host", "127.0.0.1"]) == 0
    procs = []
    for rank in range(3):
        env = dict(os.environ, SLURM_PROCID=str(rank), SLURM_NTASKS="3", SLURM_TASKS_PER_NODE="3",
                   SLURM_JOB_ID="test", SLURM_CPUS_PER_TASK="1", SPH_NODES="127.0.0.1",
                   SPH_LISTEN_HOST="127.0.0.1", SPH_BASE_PORT=str(base), SPH_PYTHON=sys.executable, SPH_TLS=str(tls))
        procs.append(subprocess.Popen(["bash", "launch/slurm/peer.sh", DAM, *SMALL, "--out", str(out)], cwd=ROOT,
                                      env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    # When they run, each computing the others' endpoints from its rank
    errors = [p.communicate(timeout=300)[1] for p in procs]
    assert [p.returncode for p in procs] == [0, 0, 0], errors
    assert_same(reference, out)


def test_slurm_task_script_refuses_tasks_that_do_not_fit():
    env = dict(os.environ, SLURM_PROCID="0", SLURM_NTASKS="4", SLURM_NTASKS_PER_NODE="1", SPH_NODES="a b")
    done = subprocess.run(["bash", "launch/slurm/peer.sh", DAM], cwd=ROOT, env=env, capture_output=True, text=True)
    assert done.returncode == 2 and "4 tasks do not fit 2 nodes x 1 tasks per node" in done.stderr


FAKE_SRUN = '''import os, signal, subprocess, sys, time
args = [a for a in sys.argv[1:] if not a.startswith("--kill-on-bad-exit")]
n = int(os.environ["SLURM_NTASKS"])
procs = [subprocess.Popen(args, env=dict(os.environ, SLURM_PROCID=str(r), SLURM_LOCALID=str(r))) for r in range(n)]
while True:  # --kill-on-bad-exit: the first task that fails takes the others down
    codes = [p.poll() for p in procs]
    bad = [c for c in codes if c not in (None, 0)]
    if bad or all(c is not None for c in codes):
        break
    time.sleep(0.05)
for p in procs:
    if p.poll() is None:
        p.kill()
    p.wait()
sys.exit(0 if not bad else (bad[0] if bad[0] > 0 else 128 - bad[0]))
'''


def test_slurm_batch_script_restarts_the_tasks_from_the_newest_checkpoint(tmp_path):
    # Given the batch script with a stand-in srun (two tasks on this node), TLS and one restart allowed
    scene = ["configs/dam_break_2d.toml", "--set", "particles.spacing=0.01", "--precision", "f64",
             "--steps", "600", "--checkpoint-every", "40"]
    assert main(["run", *scene, "--out", str(tmp_path / "one"), "--quiet"]) == 0
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "srun").write_text(f"#!{sys.executable}\n" + FAKE_SRUN)
    (bin_dir / "srun").chmod(0o755)
    out = tmp_path / "out"
    env = dict(os.environ, PATH=f"{bin_dir}:{os.environ['PATH']}", SLURM_NTASKS="2", SLURM_NTASKS_PER_NODE="2",
               SLURM_JOB_ID="restart", SLURM_SUBMIT_DIR=str(ROOT), SPH_NODES="127.0.0.1",
               SPH_BASE_PORT=str(free_ports(1)[0]), SPH_PYTHON=sys.executable, SPH_RESTARTS="1",
               SPH_TLS=str(tmp_path / "tls"))
    job = subprocess.Popen(["bash", "launch/slurm/sph.sbatch", *scene, "--out", str(out)], cwd=ROOT, env=env,
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        # When task 1 is killed after the first checkpoint
        deadline = time.monotonic() + 120
        while not (out / "checkpoints" / "latest").exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert (out / "checkpoints" / "latest").exists()
        victims = [pid for pid, cmd in peers_running() if "--rank" in cmd and cmd[cmd.index("--rank") + 1] == "1"
                   and str(out) in " ".join(cmd)]
        assert victims
        for pid in victims:
            os.kill(pid, signal.SIGKILL)
        err = job.communicate(timeout=300)[1]
    finally:
        if job.poll() is None:
            os.killpg(job.pid, signal.SIGKILL)
    # Then the job restarts both tasks from the checkpoint and ends with one process's bits
    assert job.returncode == 0, err[-3000:]
    assert "restarting from" in err and "restart 1 of 1" in err, err[-3000:]
    one, got = np.load(tmp_path / "one" / "final.npz"), np.load(out / "final.npz")
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(one[key], got[key]), key
    assert not (tmp_path / "tls").exists()  # the job's credentials went with it


def peers_running():
    """(pid, argv) of every `launch.cli peer` process on this machine."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                cmd = (entry / "cmdline").read_bytes().decode().split("\0")
            except OSError:
                continue
            if "launch.cli" in cmd and "peer" in cmd:
                found.append((int(entry.name), cmd))
    return found


def test_a_run_started_in_a_folder_with_planted_packages_runs_this_code_in_every_process(tmp_path):
    # Given a folder holding packages named like ours (another checkout's, or anybody's in /tmp), each
    # leaving a mark when imported
    from sphcore.children import module_env
    marks = []
    for package in ("sphcore", "nodes", "launch"):
        (tmp_path / package).mkdir()
        marks.append(tmp_path / f"{package} ran")
        (tmp_path / package / "__init__.py").write_text(f"open({str(marks[-1])!r}, 'w').close()\n")
    # When a 2-peer run with its viewer is started from there (the launcher itself as `sph` is: its
    # folder not on the path)
    launcher = [sys.executable, "-P", "-c", "import sys; from launch.cli import main; sys.exit(main())"]
    done = subprocess.run(launcher + ["run", str(ROOT / "configs" / "tiny.toml"), "--peers", "2", "--steps", "3",
                                      "--precision", "f64", "--out", str(tmp_path / "out"), "--quiet"],
                          cwd=tmp_path, env=module_env(), capture_output=True, text=True, timeout=600)
    # Then it ran, and no process (peers, viewer, compile helper) imported the planted code
    assert done.returncode == 0, done.stderr[-3000:]
    assert (tmp_path / "out" / "final.npz").exists()
    assert not any(m.exists() for m in marks), [m.name for m in marks if m.exists()]
