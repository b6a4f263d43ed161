"""Where a peer process's CPU goes: its step loop's thread against Zenoh's and the others, and its
stage totals, in a `sph run --peers P` of the bench's 3D dam break (the spacing of ``sph bench
--sizes N``, its fixed step, balance every 50 steps, f32, 1 thread a peer, 400 timed steps).

    .venv/bin/python scripts/investigations/peer_thread_cpu.py [--particles 50000] [--peers 2] [--insecure]

Prints the run's particle-steps/s, each peer's CPU seconds by thread (read from /proc while it runs)
and its stage, wait and step totals from summary.json. About 15 s a run on 2 cores at 50,000.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from launch.bench import _fixed, spacing_for  # noqa: E402
from sphcore.children import module_command, module_env  # noqa: E402

SCENE = ROOT / "configs" / "dam_break.toml"
TICK = os.sysconf("SC_CLK_TCK")


def peers_of(pid: int) -> dict:
    """{rank: pid} of the launcher's peer processes."""
    out = {}
    for p in Path("/proc").iterdir():
        if not p.name.isdigit():
            continue
        try:
            if int((p / "stat").read_text().split()[3]) != pid:
                continue
            cmd = (p / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"--rank" in cmd:
            out[cmd[cmd.index(b"--rank") + 1].decode()] = int(p.name)
    return out


def thread_cpu(pid: int) -> dict:
    """{thread id: (name, CPU seconds)} of process ``pid``."""
    out = {}
    for t in Path(f"/proc/{pid}/task").iterdir():
        try:
            stat = (t / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        out[int(t.name)] = (stat[stat.index("(") + 1:stat.rindex(")")], (int(fields[11]) + int(fields[12])) / TICK)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--particles", type=int, default=50000)
    ap.add_argument("--peers", type=int, default=2)
    ap.add_argument("--insecure", action="store_true", help="plain TCP instead of TLS")
    args = ap.parse_args()
    dx = spacing_for(SCENE, args.particles)
    with tempfile.TemporaryDirectory() as tmp:
        cmd = module_command("launch.cli", "run", str(SCENE), "--peers", str(args.peers), "--threads", "1",
                             "--steps", "401", "--precision", "f32", "--out", tmp, "--quiet", "--no-viewer",
                             "--set", "decomposition.balance_every=50", *(["--insecure"] if args.insecure else []))
        for kv in _fixed(SCENE, dx):
            cmd += ["--set", kv]
        p = subprocess.Popen(cmd, env=module_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        last = {}
        while p.poll() is None:
            for rank, pid in peers_of(p.pid).items():
                last[rank] = (pid, thread_cpu(pid))
            time.sleep(0.3)
        _, err = p.communicate()
        if p.returncode != 0:
            sys.exit(f"the run failed ({p.returncode}): {err[-2000:]}")
        s = json.loads((Path(tmp) / "summary.json").read_text())
    loop = s["loop"]
    print(f"{s['particles']} particles, {args.peers} peer(s): {s['particles'] * loop['steps'] / loop['wall_s']:.3g} "
          f"particle-steps/s over {loop['steps']} steps")
    for rank, (pid, threads) in sorted(last.items()):
        others = {}
        for tid, (name, cpu) in threads.items():
            if tid != pid:
                others[name] = others.get(name, 0.0) + cpu
        print(f"rank {rank}: step loop's thread {threads.get(pid, ('', 0.0))[1]:.1f} s CPU, the others "
              f"{sum(others.values()):.1f} s", {k: round(v, 2) for k, v in others.items() if v > 0.05})
    for peer in s.get("per_peer", []):
        print(f"rank {peer['rank']}: step {peer['step_s_total']:.2f} s, waited {peer['wait_s_total']:.2f} s, stages",
              {k: round(v, 2) for k, v in peer["stages"].items()})
    if "per_peer" not in s:
        print("stages", {k: round(v["total_s"], 2) for k, v in s.get("stages", {}).items() if isinstance(v, dict)})


if __name__ == "__main__":
    main()
