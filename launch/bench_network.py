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
summary: the stepping loop only, without compilation), and the ratios are to loopback TLS.
"""
from __future__ import annotations

import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from launch import netns

DELAYS_MS = (0.0, 1.0, 5.0)
PORT = 7447


def _run(cmd: list[str], out: Path) -> float | None:
    done = subprocess.run(cmd + ["--out", str(out), "--quiet"], capture_output=True, text=True)
    if done.returncode != 0:
        print(f"  failed ({done.returncode}): {done.stderr[-1500:]}", file=sys.stderr)
        return None
    return json.loads((out / "summary.json").read_text())["particle_steps_per_s"]


def network_cases(scene_path: Path, fixed: list[str], steps: int, precision: str, repeat: int) -> list[dict]:
    base = [sys.executable, "-m", "launch.cli", "run", str(scene_path), "--steps", str(steps + 1), "--precision",
            precision, "--threads", "1", "--no-viewer"]
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
                figures[name].append(value)
            print(f"  round {round_ + 1}/{repeat}  {name:<34} "
                  f"{value:.3e} particle-steps/s" if value else f"  {name}: failed", flush=True)
    results = []
    reference = statistics.median(figures["loopback, TLS"]) if figures["loopback, TLS"] else None
    print("\n2-peer dam break, median particle-steps/s (ratio to loopback TLS):")
    for name, delay, extra in cases:
        if not figures[name]:
            continue
        median = statistics.median(figures[name])
        ratio = median / reference if reference else None
        results.append({"case": name, "delay_ms": delay, "insecure": "--insecure" in extra,
                        "overlap": "decomposition.overlap=false" not in extra, "runs": figures[name],
                        "particle_steps_per_s": median, "ratio_to_loopback_tls": ratio})
        print(f"  {name:<34} {median:.3e}  ({ratio:.3f}x)" if ratio else f"  {name:<34} {median:.3e}")
    return results
