"""A peer's endpoint on Zenoh, with the interface of ``nodes.transport`` (send / recv).

Each peer opens one Zenoh session in peer mode: multicast scouting off, listening on its own
endpoint and connecting explicitly to the others' (a full mesh, no router needed). It subscribes
to its inbox (``wire.inbox_key``) and declares a liveliness token; the subscriber callback (a Zenoh
thread) decodes each message, drops anything malformed or foreign with a log line, and files the
arrays in a mailbox keyed by (source, step, phase). ``recv`` blocks on that mailbox with a timeout.

If a peer of the run disappears (its process died, or its links are lost for longer than the lease),
its token vanishes and every waiting peer raises ``PeerLost`` at once; a peer that is merely slow
makes ``recv`` raise ``PeerTimeout`` naming it and the step.
"""
from __future__ import annotations

import json
import logging
import threading
import time

from nodes import wire

log = logging.getLogger("sph.zenoh")


class TransportError(RuntimeError):
    pass


class PeerLost(TransportError):
    pass


class PeerTimeout(TransportError):
    pass


LEASE_MS = 5000


def zenoh_config(listen: list[str], connect: list[str], lease_ms: int = LEASE_MS):
    """Peer-mode configuration: explicit endpoints only (no multicast scouting, no gossip: every
    launcher connects each peer to all lower ranks, a full mesh). A peer whose process
    ends is gone at once (its sockets close); one whose links go silent (machine or network down) is
    declared gone after ``lease_ms``. Shorter leases flap on an overloaded machine (seen with 64 peers
    on 2 cores at 1 s)."""
    import zenoh
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("peer"))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")  # links only where --listen/--connect say
    conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    conf.insert_json5("transport/link/tx/lease", str(int(lease_ms)))
    conf.insert_json5("transport/link/tx/keep_alive", "4")
    return conf


class ZenohEndpoint:
    """Peer ``rank`` of a ``world``-peer run ``run`` on Zenoh."""

    def __init__(self, run: str, rank: int, world: int, listen: list[str], connect: list[str],
                 timeout: float = 120.0, lease_ms: int = LEASE_MS):
        import zenoh
        self.run = wire.check_run_id(run)
        self.rank, self.world, self.timeout = rank, world, timeout
        self._zenoh = zenoh
        self._cv = threading.Condition()
        self._mail = {}           # (source, step, phase) -> arrays
        self._alive = set()       # ranks whose liveliness token is present
        self._lost = set()        # ranks whose token appeared, then vanished
        self._closing = False
        self.dropped = 0          # malformed or foreign messages
        self.bytes_sent = {}      # phase -> bytes on the wire (headers included)
        self.wait_s = {}          # phase -> seconds blocked in recv
        self.session = zenoh.open(zenoh_config(listen, connect, lease_ms))
        self._publishers = {}
        self._sub = self.session.declare_subscriber(wire.inbox_key(self.run, rank), self._on_message)
        self._live_sub = self.session.liveliness().declare_subscriber(wire.alive_all(self.run), self._on_alive,
                                                                      history=True)
        self.commands = []        # rank 0: control commands received (nodes/control.py), not yet announced
        if rank == 0:
            self._control_sub = self.session.declare_subscriber(wire.control_key(self.run), self._on_control)
        # declared after the inbox subscriber: whoever sees this token can already reach us
        self._token = self.session.liveliness().declare_token(wire.alive_key(self.run, rank))

    # -- Zenoh callbacks (Zenoh's threads) ----------------------------------------------------------
    def _on_message(self, sample):
        try:
            source, (step, phase), arrays = wire.decode(sample.payload.to_bytes(), self.run, self.rank, self.world)
        except wire.WireError as e:
            self.dropped += 1
            log.warning("peer %d: dropped a message on %s: %s", self.rank, sample.key_expr, e)
            return
        with self._cv:
            key = (source, step, phase)
            if key in self._mail:
                self.dropped += 1
                log.warning("peer %d: dropped a duplicate %s message of step %d from peer %d",
                            self.rank, phase, step, source)
                return
            self._mail[key] = arrays
            self._cv.notify_all()

    def _on_control(self, sample):
        from nodes import control
        try:
            _, _, arrays = wire.decode(sample.payload.to_bytes(), self.run, 0, self.world, sources=(wire.CONTROLLER,))
            command = control.parse(bytes(arrays["command"]).decode())
        except (wire.WireError, ValueError, KeyError, UnicodeDecodeError) as e:
            log.warning("peer 0: ignored a control message: %s", e)
            return
        with self._cv:
            self.commands.append(command)
            self._cv.notify_all()

    def take_commands(self) -> list:
        with self._cv:
            out, self.commands = self.commands, []
        return out

    def _on_alive(self, sample):
        try:
            rank = wire.rank_from_key(sample.key_expr)
        except ValueError:
            return
        if not 0 <= rank < self.world:
            return
        with self._cv:
            if sample.kind == self._zenoh.SampleKind.PUT:
                self._alive.add(rank)
            elif rank in self._alive:
                self._alive.discard(rank)
                if not self._closing:
                    self._lost.add(rank)
            self._cv.notify_all()

    # -- the transport interface ------------------------------------------------------------------
    def send(self, dest: int, tag: tuple, arrays: dict):
        step, phase = tag
        payload = wire.encode(self.run, step, phase, self.rank, dest, arrays)
        pub = self._publishers.get(dest)
        if pub is None:
            pub = self.session.declare_publisher(wire.halo_key(self.run, dest, self.rank),
                                                 congestion_control=self._zenoh.CongestionControl.BLOCK,
                                                 reliability=self._zenoh.Reliability.RELIABLE)
            self._publishers[dest] = pub
        pub.put(payload)
        self.bytes_sent[phase] = self.bytes_sent.get(phase, 0) + len(payload)

    def _frame_publisher(self):
        pub = self._publishers.get("frame")
        if pub is None:
            pub = self.session.declare_publisher(wire.frame_key(self.run, self.rank),
                                                 congestion_control=self._zenoh.CongestionControl.DROP)
            self._publishers["frame"] = pub
        return pub

    def viewer_listening(self) -> bool:
        """Whether a viewer is subscribed to our framelets (peers render only then)."""
        return self._frame_publisher().matching_status.matching

    def publish_frame(self, step: int, phase: str, arrays: dict, reliable: bool = False):
        """Publish to any viewer: framelets are dropped rather than wait when the link is congested
        (peers never wait for a viewer); the end-of-run notice is reliable."""
        from nodes.viewer import VIEWER
        payload = wire.encode(self.run, step, phase, self.rank, VIEWER, arrays)
        if reliable:
            self.session.put(wire.frame_key(self.run, self.rank), payload,
                             congestion_control=self._zenoh.CongestionControl.BLOCK)
        else:
            self._frame_publisher().put(payload)
        self.bytes_sent["frames"] = self.bytes_sent.get("frames", 0) + len(payload)

    def recv(self, source: int, tag: tuple):
        """Generator with the in-process interface; it blocks instead of yielding."""
        return self.wait(source, tag)
        yield  # pragma: no cover

    def wait(self, source: int, tag: tuple) -> dict:
        step, phase = tag
        key = (source, step, phase)
        t0 = time.perf_counter()
        deadline = t0 + self.timeout
        with self._cv:
            while key not in self._mail:
                if phase != "bye" or source in self._lost:  # at the end, peers that got their bye leave
                    self._check_lost(step, phase)
                left = deadline - time.perf_counter()
                if left <= 0:
                    state = "alive" if source in self._alive else "not connected"
                    raise PeerTimeout(f"peer {self.rank}, step {step}: no {phase!r} message from peer {source} "
                                      f"({state}) after {self.timeout:g} s")
                self._cv.wait(min(left, 0.5))
            arrays = self._mail.pop(key)
        self.wait_s[phase] = self.wait_s.get(phase, 0.0) + time.perf_counter() - t0
        return arrays

    def _check_lost(self, step, phase):
        if self._lost:
            lost = ", ".join(str(r) for r in sorted(self._lost))
            raise PeerLost(f"peer {self.rank}, step {step} ({phase}): peer {lost} left the run "
                           "(process ended or its network link was lost)")

    def check(self):
        """Raise PeerLost if a peer of the run has gone (called between steps)."""
        with self._cv:
            self._check_lost(-1, "between steps")

    def wait_for_peers(self, timeout: float | None = None):
        """Block until every peer of the run has declared its token (so its inbox is subscribed)."""
        timeout = self.timeout if timeout is None else timeout
        deadline = time.perf_counter() + timeout
        with self._cv:
            while len(self._alive) < self.world:
                self._check_lost(-1, "start-up")
                left = deadline - time.perf_counter()
                if left <= 0:
                    missing = sorted(set(range(self.world)) - self._alive)
                    raise PeerTimeout(f"peer {self.rank}: peers {missing} did not join run {self.run!r} within "
                                      f"{timeout:g} s (check their --listen/--connect endpoints)")
                self._cv.wait(min(left, 0.5))

    def wait_until_alone(self, timeout: float = 10.0):
        """Rank 0 at the end: wait for the other peers to leave (they do once they have our "bye"),
        so that closing our session cannot cut off a message still on its way."""
        deadline = time.perf_counter() + timeout
        with self._cv:
            self._closing = True  # peers leaving now is the plan, not a loss
            while self._alive - {self.rank}:
                left = deadline - time.perf_counter()
                if left <= 0:
                    log.warning("peer %d: peers %s still connected %g s after the end of the run", self.rank,
                                sorted(self._alive - {self.rank}), timeout)
                    return
                self._cv.wait(min(left, 0.5))

    def close(self):
        with self._cv:
            self._closing = True
        try:
            self._token.undeclare()
            self.session.close()
        except Exception as e:  # closing must not hide the error that brought us here
            log.debug("peer %d: zenoh close: %s", self.rank, e)
