"""How long does a small message take between two peer processes over Zenoh on one machine, idle
and while both are busy computing? Two processes (spawned) open a ZenohEndpoint each (plain TCP on
loopback, as --insecure; ports 17500 and 17501), then exchange one small message per round, the
way the time-step reduction does: each computes for --busy ms holding the GIL (as a numba kernel
does), sends, and waits for the other's. The wait is a one-way latency plus any difference in
arrival; printed as median and mean per process.

    .venv/bin/python scripts/investigations/zenoh_latency.py [--busy 5] [--rounds 500] [--bytes 32]

The time of the send call itself (encode and hand to Zenoh) is printed beside the wait.
"""
import argparse
import multiprocessing as mp
import time

import numpy as np


def peer(rank, rounds, busy_ms, out, nbytes=32):
    from nodes.zenoh_transport import ZenohEndpoint
    ports = (17500, 17501)
    ep = ZenohEndpoint("latency", rank, 2, [f"tcp/127.0.0.1:{ports[rank]}"],
                       [f"tcp/127.0.0.1:{ports[0]}"] if rank == 1 else [])
    ep.wait_for_peers(30)
    other, arrays, waits, sends = 1 - rank, {"v": np.zeros(max(nbytes // 8, 1))}, [], []
    for step in range(rounds):
        ep.at_step(step)
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < busy_ms / 1000:
            pass
        t0 = time.perf_counter()
        ep.send(other, (step, "reduce"), arrays)
        sends.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        ep.wait(other, (step, "reduce"))
        waits.append(time.perf_counter() - t0)
    out.put((rank, float(np.median(waits)) * 1e3, float(np.mean(waits)) * 1e3, float(np.median(sends)) * 1e3,
             float(np.mean(sends)) * 1e3))
    time.sleep(1.0)  # let the other side receive our last message before the session closes
    ep.close()


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--busy", type=float, default=5.0, help="ms of computing before each message (0: idle)")
    ap.add_argument("--rounds", type=int, default=500)
    ap.add_argument("--bytes", type=int, default=32, help="payload of each message (a halo message: ~30-100 kB)")
    a = ap.parse_args()
    ctx = mp.get_context("spawn")  # never fork after zenoh.open
    out = ctx.Queue()
    procs = [ctx.Process(target=peer, args=(r, a.rounds, a.busy, out, a.bytes)) for r in range(2)]
    for p in procs:
        p.start()
    for rank, median, mean, send_median, send_mean in sorted(out.get(timeout=300) for _ in procs):
        print(f"busy {a.busy:g} ms, {a.bytes} B, process {rank}: wait median {median:.3f} ms, mean {mean:.3f} ms; "
              f"send median {send_median:.3f} ms, mean {send_mean:.3f} ms")
    for p in procs:
        p.join()


if __name__ == "__main__":
    main()
