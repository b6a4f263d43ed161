"""Two code trees side by side on two network-namespace hosts (root): the 2-peer 3D dam break
(about 20,000 particles, f32, fixed dt, 1 numba thread a peer, TLS, no viewer) with a one-way delay
added by a relay on each host, as `sph bench --network` runs it, the trees in turn for --rounds
rounds (ABAB...), after one untimed run (the first run of a session on the namespace hosts waits
~2 ms a step longer for its migrants). Prints each run's particle-steps/s and the peers' mean wait
per phase (ms a step).

    .venv/bin/python scripts/investigations/network_ab.py NEW_TREE OLD_TREE [--delays 5 1] [--rounds 3] \
        [--set "sph.solver='dfsph'" ...]

A tree is a checkout (e.g. `git worktree add /tmp/wt_old COMMIT`); each run imports only its own."""
import argparse
import os
import statistics
import subprocess
import sys
from pathlib import Path

RUN = r'''
import os, sys, tempfile
from pathlib import Path
code = sys.argv[1]
from launch import netns
from launch.bench_network import _run, PORT
from launch.bench import _fixed, spacing_for, DEFAULT_SCENE
fixed = _fixed(DEFAULT_SCENE, spacing_for(DEFAULT_SCENE, 20000))
steps, delay, sets = int(sys.argv[2]), float(sys.argv[3]), sys.argv[4:]
cmd = [sys.executable, "-m", "launch.cli", "run", str(Path(code) / "configs" / "dam_break.toml"), "--steps",
       str(steps + 1), "--precision", "f32", "--threads", "1", "--no-viewer"]
for kv in fixed + sets:
    cmd += ["--set", kv]
with tempfile.TemporaryDirectory() as tmp:
    tmp = Path(tmp)
    with netns.TestHosts(2, delay_ms=delay) as net:
        if delay:
            net.start_relays(PORT)
        cmd += ["--hosts", str(net.hosts_file(tmp, PORT)), "--ssh", net.ssh_command(tmp), "--remote-python",
                sys.executable, "--remote-dir", code]
        if net.listen_host:
            cmd += ["--listen-host", net.listen_host]
        value = _run(cmd, tmp / "out")
print(repr((value[0], value[1])) if value else "None")
'''


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("trees", nargs=2, type=Path, help="the two code trees (new, old)")
    ap.add_argument("--delays", type=float, nargs="+", default=[5.0, 1.0], help="one-way delays in ms")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a scene override for both trees' runs, after the case's own (repeatable)")
    a = ap.parse_args()
    for i, delay in enumerate(a.delays):
        speeds = {str(t): [] for t in a.trees}
        runs = [(None, a.trees[0])] if i == 0 else []
        runs += [(r, tree) for r in range(a.rounds) for tree in a.trees]
        for r, tree in runs:
            if True:
                env = dict(os.environ, PYTHONPATH=str(tree.resolve()))
                out = subprocess.run([sys.executable, "-c", RUN, str(tree.resolve()), str(a.steps), str(delay), *a.set],
                                     env=env, capture_output=True, text=True)
                value = eval(out.stdout.strip().splitlines()[-1]) if out.returncode == 0 and out.stdout.strip() else None
                if value is None:
                    print(f"{delay:g} ms {tree}: failed\n{out.stderr[-800:]}")
                    continue
                if r is None:
                    print(f"{delay:g} ms {str(tree):<24} {value[0]:.3e} particle-steps/s (untimed: the warm-up run)")
                    continue
                speeds[str(tree)].append(value[0])
                waits = ", ".join(f"{ph} {ms:.2f}" for ph, ms in value[1].items() if ms >= 0.05)
                print(f"{delay:g} ms {str(tree):<24} {value[0]:.3e} particle-steps/s; waits, ms a step: {waits}", flush=True)
        new, old = (statistics.median(speeds[str(t)]) for t in a.trees)
        print(f"{delay:g} ms: medians {new:.3e} / {old:.3e} = {new / old:.3f}x", flush=True)


if __name__ == "__main__":
    main()
