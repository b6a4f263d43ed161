"""Many-machine launchers, exercised on this machine: the hosts-file launcher (with an ssh stand-in
that runs the command locally) and the SLURM task script (with SLURM's variables set by hand)."""
import os
import subprocess
import sys
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
