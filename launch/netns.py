"""Test hosts on one machine: Linux network namespaces joined by a bridge (root only).

Each host is a namespace with one veth interface on 198.18.0.0/24 (the range set aside for network
testing, RFC 2544) and its own loopback; the bridge lives in a namespace of its own, so the machine's
own network is never touched and no packet can leave for any other address.

Delay and loss. ``tc netem`` is the usual tool, but kernels built without it exist (this project's
CI machine is one: "Specified qdisc kind is unknown"), so neither is left to it:
  - loss: an nftables rule on each host's interface drops that share of the outgoing packets at
    random (``numgen random``): real packet loss, which TCP repairs by retransmission;
  - delay and jitter: a relay process in each host (``python -m launch.netns relay``) accepts the
    connections on the host's address and forwards them to the peer listening on the host's own
    loopback, holding every chunk of bytes for delay +- jitter ms (never reordering them, as a
    TCP stream would not be). The peers then listen on 127.0.0.1 (``listen_host``) inside their
    host. One relay sits on every connection's path, in both directions, so the round trip is 2x
    the delay, as with netem on both ends' interfaces.
The ssh stand-in (``ssh_command``) runs a command
inside a host's namespace, which is all ``sph run --hosts`` needs from ssh; stdin passes through,
so the launcher's credentials reach the peer as they would over ssh.

    with TestHosts(3, delay_ms=2, jitter_ms=0.5, loss=0.1) as net:
        net.hosts           # ["198.18.0.11", "198.18.0.12", "198.18.0.13"]
        net.cut(2)          # host 2's link goes down (a partition)

Every namespace made is removed on exit, also after a failure; processes still inside are killed
first.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

SUBNET = "198.18.0"


def available() -> str | None:
    """None if test hosts can be made here, else why not."""
    if os.geteuid() != 0:
        return "network namespaces need root"
    if shutil.which("ip") is None or shutil.which("tc") is None:
        return "iproute2 (ip, tc) is not installed"
    return None


def _ip(*args, ns: str | None = None, check: bool = True):
    cmd = (["ip", "netns", "exec", ns] if ns else []) + list(args)
    return subprocess.run(cmd, check=check, capture_output=True, text=True)


class TestHosts:
    __test__ = False  # not a pytest class

    def __init__(self, n: int, delay_ms: float = 0.0, jitter_ms: float = 0.0, loss: float = 0.0):
        tag = uuid.uuid4().hex[:5]
        self.n, self.tag = n, tag
        self.delay_ms, self.jitter_ms, self.loss = delay_ms, jitter_ms, loss
        self.bridge_ns = f"sph-{tag}-br"
        self.namespaces = [f"sph-{tag}-h{i}" for i in range(n)]
        self.hosts = [f"{SUBNET}.{11 + i}" for i in range(n)]
        self._veth = [f"s{tag}h{i}" for i in range(n)]  # <= 15 characters
        self._made = []
        self._relays = []
        # with a relay, peers listen on their host's loopback and the relay on its address
        self.listen_host = "127.0.0.1" if delay_ms else None

    # -- lifecycle --------------------------------------------------------------------------------
    def __enter__(self):
        try:
            self._make()
        except BaseException:
            self.remove()
            raise
        return self

    def __exit__(self, *exc):
        self.remove()

    def _make(self):
        _ip("ip", "netns", "add", self.bridge_ns)
        self._made.append(self.bridge_ns)
        _ip("ip", "link", "add", "br0", "type", "bridge", ns=self.bridge_ns)
        _ip("ip", "link", "set", "br0", "up", ns=self.bridge_ns)
        for i, (ns, host, veth) in enumerate(zip(self.namespaces, self.hosts, self._veth)):
            _ip("ip", "netns", "add", ns)
            self._made.append(ns)
            _ip("ip", "link", "add", veth, "netns", ns, "type", "veth", "peer", "name", f"b{i}", "netns",
                self.bridge_ns)
            _ip("ip", "link", "set", f"b{i}", "master", "br0", "up", ns=self.bridge_ns)
            _ip("ip", "addr", "add", f"{host}/24", "dev", veth, ns=ns)
            _ip("ip", "link", "set", veth, "up", ns=ns)
            _ip("ip", "link", "set", "lo", "up", ns=ns)
            if self.loss:
                self._drop(i, self.loss)

    def _drop(self, i: int, percent: float):
        """Drop ``percent`` % of host i's outgoing packets at random (nftables)."""
        ns, veth = self.namespaces[i], self._veth[i]
        per_million = int(round(percent * 1e4))
        _ip("nft", "add", "table", "inet", "sphloss", ns=ns)
        _ip("nft", "add chain inet sphloss out { type filter hook output priority 0 ; }", ns=ns)
        _ip("nft", f"add rule inet sphloss out oifname {veth} numgen random mod 1000000 < {per_million} drop", ns=ns)

    def start_relays(self, port: int):
        """Relay host i's ``address:port`` to its ``127.0.0.1:port`` with the delay and jitter."""
        for ns, host in zip(self.namespaces, self.hosts):
            cmd = ["ip", "netns", "exec", ns, sys.executable, "-m", "launch.netns", "relay", f"{host}:{port}",
                   f"127.0.0.1:{port}", str(self.delay_ms), str(self.jitter_ms)]
            proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
            if proc.stdout.readline().strip() != "relay ready":
                raise RuntimeError(f"the delay relay in {ns} did not start")
            self._relays.append(proc)

    def remove(self):
        """Kill whatever still runs inside, delete every namespace made (the veths go with them)."""
        for proc in self._relays:
            proc.kill()
            proc.wait()
        self._relays = []
        for ns in self._made:
            pids = _ip("ip", "netns", "pids", ns, check=False).stdout.split()
            for pid in pids:
                try:
                    os.kill(int(pid), signal.SIGKILL)
                except (ProcessLookupError, ValueError):
                    pass
        for ns in reversed(self._made):
            _ip("ip", "netns", "delete", ns, check=False)
        self._made = []

    # -- what a test does to the network ----------------------------------------------------------
    def cut(self, i: int):
        """Host i's link goes down: a partition (its processes keep running, cut off)."""
        _ip("ip", "link", "set", self._veth[i], "down", ns=self.namespaces[i])

    def pids(self, i: int) -> list[int]:
        """Processes running inside host i (the relays excluded)."""
        relays = {p.pid for p in self._relays}
        return [int(p) for p in _ip("ip", "netns", "pids", self.namespaces[i], check=False).stdout.split()
                if int(p) not in relays]

    def ssh_command(self, folder: Path) -> str:
        """An ssh stand-in for ``sph run --ssh``: ``STANDIN HOST COMMAND`` runs COMMAND in HOST's
        namespace (written to ``folder``)."""
        table = folder / f"netns-{self.tag}.json"
        table.write_text(json.dumps(dict(zip(self.hosts, self.namespaces))))
        script = folder / f"netns-ssh-{self.tag}.py"
        script.write_text(
            "import json, os, sys\n"
            f"table = json.load(open({str(table)!r}))\n"
            "host, command = sys.argv[-2], sys.argv[-1]\n"
            "os.execvp('ip', ['ip', 'netns', 'exec', table[host], 'bash', '-c', command])\n")
        return f"{sys.executable} {script}"

    def hosts_file(self, folder: Path, port: int = 7447, threads: int = 1) -> Path:
        path = folder / f"hosts-{self.tag}.txt"
        path.write_text("".join(f"{h} {port} {threads}\n" for h in self.hosts))
        return path


def wait_gone(net: TestHosts, timeout: float) -> list[int]:
    """Wait until no process is left in any host; returns the pids still there after ``timeout``."""
    deadline = time.monotonic() + timeout
    while True:
        left = [p for i in range(net.n) for p in net.pids(i)]
        if not left or time.monotonic() > deadline:
            return left
        time.sleep(0.1)


# -- the delay relay (runs inside a host: python -m launch.netns relay LISTEN TARGET DELAY JITTER) --
def _relay(listen: str, target: str, delay_ms: float, jitter_ms: float):
    import asyncio
    import random

    rng = random.Random()
    host, port = listen.rsplit(":", 1)
    to_host, to_port = target.rsplit(":", 1)

    async def pipe(reader, writer):
        """Copy one direction, each chunk released delay +- jitter after it arrived, in order."""
        loop = asyncio.get_running_loop()
        queue = asyncio.Queue()

        async def take():
            last = 0.0
            while True:
                data = await reader.read(1 << 16)
                last = max(last, loop.time() + (delay_ms + rng.uniform(-jitter_ms, jitter_ms)) / 1000.0)
                await queue.put((last, data))
                if not data:
                    return

        async def give():
            while True:
                release, data = await queue.get()
                wait = release - loop.time()
                if wait > 0:
                    await asyncio.sleep(wait)
                if not data:
                    writer.close()
                    return
                writer.write(data)
                await writer.drain()

        try:
            await asyncio.gather(take(), give())
        except (ConnectionError, OSError):
            writer.close()

    async def serve(reader, writer):
        try:
            to_reader, to_writer = await asyncio.open_connection(to_host, int(to_port))
        except OSError:
            writer.close()
            return
        await asyncio.gather(pipe(reader, to_writer), pipe(to_reader, writer), return_exceptions=True)

    async def main():
        server = await asyncio.start_server(serve, host, int(port))
        print("relay ready", flush=True)
        async with server:
            await server.serve_forever()

    asyncio.run(main())


if __name__ == "__main__":
    if len(sys.argv) == 6 and sys.argv[1] == "relay":
        _relay(sys.argv[2], sys.argv[3], float(sys.argv[4]), float(sys.argv[5]))
    else:
        sys.exit("usage: python -m launch.netns relay HOST:PORT TARGET:PORT DELAY_MS JITTER_MS")
