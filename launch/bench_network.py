"""``sph bench --network``: what security and distance cost a 2-peer run, side by side in one go.

Cases, every one the same 3D dam break (about N particles, fixed dt, ``--steps`` timed steps,
1 numba thread per peer):

    loopback, TLS          sph run --peers 2                     (the default)
    loopback, plain TCP    sph run --peers 2 --insecure
    loopback, no overlap   sph run --peers 2 --set decomposition.overlap=false
    hosts, TLS, D ms       sph run --hosts over two network-namespace hosts (launch/netns.py),
                           D = 0, 1 and 5 ms each way (root only; skipped with the reason otherwise),
                           each also with decomposition.overlap = false (waiting for every exchange
                           before computing: what overlapping the interior rows gains)

The cases run in turn, ``--repeat`` rounds (ABCDE ABCDE ...), so a slow minute of the machine
falls on every case alike; the figure is the median of each case's particle-steps/s (the runs' own
summary: the stepping loop only, without compilation), and the ratios are to loopback TLS. Each
case also reports how long a peer waited per step in each phase (summary.json's
``wait_s_per_phase``): less noisy than the speed on a shared machine, and it shows which exchange a
latency lands on.
"""
from __future__ import annotations

import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from launch import netns
from sphcore.children import module_command, module_env

DELAYS_MS = (0.0, 1.0, 5.0)
PORT = 7447


def _run(cmd: list[str], out: Path) -> tuple[float, dict] | None:
    """(particle-steps/s, {phase: ms per step that the peers waited, the mean over peers})."""
    done = subprocess.run(cmd + ["--out", str(out), "--quiet"], capture_output=True, text=True, env=module_env())
    if done.returncode != 0:
        print(f"  failed ({done.returncode}): {done.stderr[-1500:]}", file=sys.stderr)
        return None
    summary = json.loads((out / "summary.json").read_text())
    peers = summary["per_peer"]
    steps = max(1, summary["steps"])
    phases = sorted({ph for p in peers for ph in p["wait_s_per_phase"]})
    waits = {ph: 1e3 * sum(p["wait_s_per_phase"].get(ph, 0.0) for p in peers) / len(peers) / steps for ph in phases}
    return summary["particle_steps_per_s"], waits


def network_cases(scene_path: Path, fixed: list[str], steps: int, precision: str, repeat: int) -> list[dict]:
    base = module_command("launch.cli", "run", str(scene_path), "--steps", str(steps + 1), "--precision",
                          precision, "--threads", "1", "--no-viewer")
    for kv in fixed:
        base += ["--set", kv]
    why_not = netns.available()
    no_overlap = ["--set", "decomposition.overlap=false"]
    cases = [("loopback, TLS", None, []), ("loopback, plain TCP", None, ["--insecure"]),
             ("loopback, TLS, no overlap", None, no_overlap)]
    if why_not is None:
        cases += [case for d in DELAYS_MS
                  for case in ((f"2 hosts, TLS, {d:g} ms", d, []), (f"2 hosts, TLS, {d:g} ms, no overlap", d, no_overlap))]
    else:
        print(f"  (namespace hosts skipped: {why_not})", file=sys.stderr)
    figures = {name: [] for name, _, _ in cases}
    waits = {name: [] for name, _, _ in cases}
    for round_ in range(repeat):
        for name, delay, extra in cases:
            with tempfile.TemporaryDirectory() as tmp:
                tmp = Path(tmp)
                if delay is None:
                    value = _run(base + ["--peers", "2"] + extra, tmp / "out")
                else:
                    with netns.TestHosts(2, delay_ms=delay) as net:
                        if delay:
                            net.start_relays(PORT)
                        cmd = base + extra + ["--hosts", str(net.hosts_file(tmp, PORT)), "--ssh", net.ssh_command(tmp),
                                      "--remote-python", sys.executable,
                                      "--remote-dir", str(Path(__file__).resolve().parent.parent)]
                        if net.listen_host:
                            cmd += ["--listen-host", net.listen_host]
                        value = _run(cmd, tmp / "out")
            if value is not None:
                figures[name].append(value[0])
                waits[name].append(value[1])
            print(f"  round {round_ + 1}/{repeat}  {name:<34} {value[0]:.3e} particle-steps/s, waiting "
                  + ", ".join(f"{ph} {ms:.1f}" for ph, ms in value[1].items() if ms >= 0.05) + " ms/step"
                  if value else f"  {name}: failed", flush=True)
    results = []
    reference = statistics.median(figures["loopback, TLS"]) if figures["loopback, TLS"] else None
    print("\n2-peer dam break, median particle-steps/s (ratio to loopback TLS):")
    for name, delay, extra in cases:
        if not figures[name]:
            continue
        median = statistics.median(figures[name])
        ratio = median / reference if reference else None
        phases = sorted({ph for w in waits[name] for ph in w})
        wait_ms = {ph: statistics.median(w.get(ph, 0.0) for w in waits[name]) for ph in phases}
        results.append({"case": name, "delay_ms": delay, "insecure": "--insecure" in extra,
                        "overlap": "decomposition.overlap=false" not in extra, "runs": figures[name],
                        "particle_steps_per_s": median, "ratio_to_loopback_tls": ratio,
                        "wait_ms_per_step": wait_ms,
                        "wait_note": "per phase: ms per step a peer spent blocked in recv (mean over peers, "
                                     "median over runs)"})
        print(f"  {name:<34} {median:.3e}  ({ratio:.3f}x)" if ratio else f"  {name:<34} {median:.3e}")
    return results
