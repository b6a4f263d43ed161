"""A peer's endpoint on Zenoh: ``nodes.endpoint.Endpoint`` between processes.

Each peer opens one Zenoh session in peer mode: multicast scouting off, listening on its own
endpoint and connecting explicitly to the others' (a full mesh, no router needed). It subscribes
to its inbox (``wire.inbox_key``) and declares a liveliness token; the subscriber callback (a Zenoh
thread) decodes each message and files the arrays in a ``nodes.transport.Mailbox`` keyed by
(source, step, phase). ``recv`` blocks on that mailbox with a timeout and takes the first message
that passes the receiver's check (sphcore/halo.py).

Nothing that arrives is trusted: a message is dropped, counted by source and reason (``drops``,
which go into summary.json) and logged at most once per reason per second, if it is malformed or
of another run (``wire.decode``), if the source in its header is not the one its key expression
names (the key is what Zenoh access control lets only that peer publish on), if it is longer than
the run's largest message of its phase, outside the step window around this peer's step (replays
and messages from the future), a duplicate, beyond the per-source bounds of the mailbox, or
rejected by the receiver's check. Control commands are taken only from the controller's key and
acknowledged on ``wire.ack_key`` by rank 0 (nodes/peer.py).

A message that does not come is asked for again: while a peer waits for a message from a connected
peer that has been silent as long as the "not answering" warning takes, it sends that peer a small
request (phase ``resend``, the wanted phase's name as its one array) each time it warns. Every peer
keeps the messages it sent in its current step and the ``KEEP_STEPS`` before and, on its next send
or wait, sends the asked one again, the same bytes, at most ``MAX_RESENDS`` times each. A request for a message not
sent yet is ignored (a slow peer sends it anyway); the receiver takes the first copy and ignores the
others without counting them as drops. Both sides count what they did (``resends``, summary.json).
Zenoh's links are reliable, so this is a guard, not the transport: a run once hung here with each of
two peers waiting for the other's message of one step and neither in the other's mailbox.

If a peer of the run disappears, its token vanishes and every waiting peer raises ``PeerLost`` at
once, saying whether it left (its links closed while it was talking: its process ended) or went
quiet first and timed out a lease later (stopped or hung, or its machine or network down). A peer
that is connected but silent is reported as "not answering for T s (still connected)" while we
wait, and ``recv`` raises ``PeerTimeout`` naming it and the step after ``timeout`` seconds.
"""
from __future__ import annotations

import json
import logging
import re
import threading
import time

import numpy as np

from nodes import control, security, wire
from nodes.endpoint import PeerLost, PeerTimeout, TransportError
from nodes.transport import STEP_WINDOW, CountsDrops, DropLog, Mailbox
from sphcore.halo import Reject

log = logging.getLogger("sph.zenoh")


__all__ = ["PeerLost", "PeerTimeout", "TransportError", "ZenohEndpoint", "zenoh_config"]

LEASE_MS = 5000
NOT_ANSWERING_S = 2.0   # a connected peer silent this long (while we wait for it) is reported
SILENT_FRACTION = 0.8   # a token that vanishes after this fraction of a lease of silence: a link timed out
PENDING_FACTOR = 4      # bytes waiting per source: this many of the largest message of the phase
RESEND = "resend"       # the phase of a request to send a message again (never a halo phase)
KEEP_STEPS = 2          # a peer keeps what it sent this step and the two before (a neighbour is never
                        # more than one step behind: every step ends in an all-to-all reduction)
MAX_RESENDS = 3         # copies of one message sent again, however often it is asked for
MAX_REQUESTS = 64       # requests waiting to be served (more are dropped: a genuine peer asks for one)
_RANK = re.compile(r"^[0-9]{1,9}$")


def zenoh_config(listen: list[str], connect: list[str], lease_ms: int = LEASE_MS, trust=None):
    """Peer-mode configuration: explicit endpoints only (no multicast scouting, no gossip: every
    launcher connects each peer to all lower ranks, a full mesh). A peer whose process
    ends is gone at once (its sockets close); one whose links go silent (machine or network down) is
    declared gone after ``lease_ms``. Shorter leases flap on an overloaded machine (seen with 64 peers
    on 2 cores at 1 s). ``trust`` (nodes/security.Trust): mutually authenticated TLS and the run's
    access-control list; None only for ``--insecure`` runs."""
    import zenoh
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("peer"))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")  # links only where --listen/--connect say
    conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    conf.insert_json5("transport/link/tx/lease", str(int(lease_ms)))
    conf.insert_json5("transport/link/tx/keep_alive", "4")
    if trust is not None:
        security.apply(conf, trust)
    return conf


class ZenohEndpoint(CountsDrops):
    """Peer ``rank`` of a ``world``-peer run ``run`` on Zenoh."""

    def __init__(self, run: str, rank: int, world: int, listen: list[str], connect: list[str],
                 timeout: float = 120.0, lease_ms: int = LEASE_MS, trust=None,
                 window: int = STEP_WINDOW, not_answering_s: float = NOT_ANSWERING_S):
        import zenoh
        self.run = wire.check_run_id(run)
        self.rank, self.world, self.timeout = rank, world, timeout
        self._zenoh = zenoh
        self.lease_s = lease_ms / 1000.0
        self.not_answering_s = not_answering_s
        self._cv = threading.Condition()
        self._drops = DropLog(f"peer {rank}", log)  # what was dropped, by source and reason (``drops``)
        self._mail = Mailbox(self._drops, window)     # (source, step, phase) -> candidates
        self._message_limit = None  # (phase, step) -> largest genuine message (set_message_limit)
        self._alive = set()       # ranks whose liveliness token is present
        self._lost = {}           # rank whose token appeared, then vanished -> seconds it had been silent
        self._heard = {}          # rank -> monotonic time of its last message on its own key
        self._usual_wait = {}     # rank -> moving average of the waits that ended with a message from it
        self._closing = False
        self.bytes_sent = {}      # phase -> bytes on the wire (headers included)
        self._sent = {}           # (dest, step, phase) -> the payload sent, this step and KEEP_STEPS before
        self._sent_step = -1      # the latest step this peer sent a message of
        self._requests = []       # (requester, step, phase) asked for again, not served yet
        self._served = {}         # (requester, step, phase) -> copies sent again
        self._asked = {}          # (source, step, phase) -> times this peer asked for it again
        self._asked_again = {}    # source -> requests this peer sent it (summary.json "resends")
        self._sent_again = {}     # requester -> messages sent to it again
        self.wait_s = {}          # phase -> seconds blocked in recv
        self.session = zenoh.open(zenoh_config(listen, connect, lease_ms, trust))
        self._publishers = {}
        self._sub = self.session.declare_subscriber(wire.inbox_key(self.run, rank), self._on_message)
        self._live_sub = self.session.liveliness().declare_subscriber(wire.alive_all(self.run), self._on_alive,
                                                                      history=True)
        self.commands = []        # rank 0: control commands received ({"id", "text"}), not yet taken
        if rank == 0:
            self._control_sub = self.session.declare_subscriber(wire.control_key(self.run), self._on_control)
        # declared after the inbox subscriber: whoever sees this token can already reach us
        self._token = self.session.liveliness().declare_token(wire.alive_key(self.run, rank))

    # -- Zenoh callbacks (Zenoh's threads) ----------------------------------------------------------
    def _label(self, key) -> str:
        """Who published on ``key``, as far as the key says: its last segment when that is a rank of
        this run (with access control, only that peer may publish there), else "other" (so that
        made-up keys cannot grow the drop counts without bound)."""
        segment = str(key).rsplit("/", 1)[-1]
        return segment if _RANK.match(segment) and int(segment) < self.world else "other"

    def _on_message(self, sample):
        key = str(sample.key_expr)
        label = self._label(key)
        payload = sample.payload.to_bytes()
        try:
            source, (step, phase), arrays = wire.decode(payload, self.run, self.rank, self.world)
        except wire.WireError as e:
            self._drops(label, e.reason, f"on {key}: {e}")
            return
        if str(source) != label:  # the key is what access control vouches for; the header must agree
            self._drops(label, "wrong key", f"step {step} {phase!r} on {key} says it is from peer {source}")
            return
        if phase == RESEND:
            self._on_request(source, step, arrays)
            return
        limit = self.message_limit(phase, step)
        if len(payload) > limit:
            self._drops(label, "oversized", f"step {step} {phase!r}: {len(payload)} bytes, this run's largest "
                                            f"{phase!r} message is {limit} bytes")
            return
        with self._cv:
            self._heard[source] = time.monotonic()
            if self._mail.put(source, step, phase, arrays, len(payload), payload, PENDING_FACTOR * limit,
                              asked=(source, step, phase) in self._asked):
                self._cv.notify_all()

    def _on_request(self, source: int, step: int, arrays: dict):
        """Peer ``source`` asks for our message of ``step`` whose phase ``arrays["phase"]`` names
        (ASCII bytes): queued for the step loop (``_serve_requests``), which may block on the link."""
        wanted = arrays.get("phase")
        name = None
        if (set(arrays) == {"phase"} and wanted.dtype == np.uint8 and wanted.ndim == 1
                and 1 <= wanted.shape[0] <= 32):
            name = bytes(wanted).decode("ascii", "replace")
        if name is None or not wire.is_phase(name) or name == RESEND:
            self._drops(source, "malformed", f"step {step} {RESEND!r}: the arrays must be one 'phase', the "
                                             "ASCII name of a phase (uint8, 1-32 bytes)")
            return
        with self._cv:
            if len(self._requests) >= MAX_REQUESTS:
                self._drops(source, "inbox full", f"step {step} {RESEND!r}: {MAX_REQUESTS} requests already wait")
                return
            self._requests.append((source, step, name))
            self._cv.notify_all()

    def _serve_requests(self):
        """Send again what peers asked for (the step loop's thread, never the lock holder): a message
        this peer keeps is sent as it was, at most MAX_RESENDS times; one older than what it keeps, or
        further ahead than a peer of this run can be, is a drop; one not sent yet is left to come."""
        if not self._requests:  # the usual case, every send and wait: no lock (a request filed meanwhile waits
            return              # for the next call)
        with self._cv:
            requests, self._requests = self._requests, []
            now = max(self._sent_step, -1 if self._mail.step is None else self._mail.step)
        for key in requests:
            requester, step, phase = key
            what = f"step {step} {phase!r}"
            payload = self._sent.get(key)
            if payload is None:
                if step < now - KEEP_STEPS or step > now + STEP_WINDOW:
                    self._drops(requester, "resend unknown", f"{what} asked for again: this peer is at step "
                                                             f"{now} and keeps {KEEP_STEPS} steps back")
                continue
            served = self._served.get(key, 0)
            if served >= MAX_RESENDS:
                self._drops(requester, "resend limit", f"{what} asked for again: already sent {MAX_RESENDS} more times")
                continue
            self._served[key] = served + 1
            self._sent_again[requester] = self._sent_again.get(requester, 0) + 1
            log.warning("peer %d: peer %d asked again for our %r message of step %d; sending it again (%d of %d)",
                        self.rank, requester, phase, step, served + 1, MAX_RESENDS)
            self._put(requester, payload)
            self.bytes_sent[phase] = self.bytes_sent.get(phase, 0) + len(payload)

    def _ask_again(self, source: int, step: int, phase: str):
        """Ask ``source`` to send its ``phase`` message of ``step`` again (``_on_request`` there)."""
        key = (source, step, phase)
        with self._cv:
            self._asked[key] = self._asked.get(key, 0) + 1
            for old in [k for k in self._asked if k[1] < step - KEEP_STEPS]:
                del self._asked[old]
        self._asked_again[source] = self._asked_again.get(source, 0) + 1
        payload = wire.encode(self.run, step, RESEND, self.rank, source,
                              {"phase": np.frombuffer(phase.encode("ascii"), dtype=np.uint8)})
        self._put(source, payload)
        self.bytes_sent[RESEND] = self.bytes_sent.get(RESEND, 0) + len(payload)

    def _on_control(self, sample):
        """A command on the controller's key (with access control, only the controller's identity may
        publish there): queued for rank 0's step loop, which validates and acknowledges it."""
        try:
            _, (_, phase), arrays = wire.decode(sample.payload.to_bytes(), self.run, 0, self.world,
                                                sources=(wire.CONTROLLER,), max_bytes=control.MAX_MESSAGE)
            command = control.read_command(phase, arrays)
        except wire.WireError as e:
            self._drops("controller", e.reason, f"control message: {e}")
            return
        except ValueError as e:
            self._drops("controller", "malformed", f"control message: {e}")
            return
        with self._cv:
            if len(self.commands) >= control.MAX_PENDING:
                self._drops("controller", "inbox full", f"{control.MAX_PENDING} commands already wait")
                return
            self.commands.append(command)
            self._cv.notify_all()

    def take_commands(self) -> list:
        """Rank 0: the commands received since the last call, as {"id", "text"}, oldest first."""
        with self._cv:
            out, self.commands = self.commands, []
        return out

    def send_ack(self, command_id: str, result: str, step: int, reason: str = ""):
        """Rank 0: answer the controller of command ``command_id`` on ``wire.ack_key``: "accepted"
        (applied after step ``step`` on every peer) or "rejected" with ``reason``."""
        payload = wire.encode(self.run, max(int(step), -1), "ack", self.rank, wire.CONTROLLER,
                              control.ack_arrays(command_id, result, reason))
        self.session.put(wire.ack_key(self.run), payload, congestion_control=self._zenoh.CongestionControl.BLOCK)

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
                    heard = self._heard.get(rank)
                    self._lost[rank] = None if heard is None else time.monotonic() - heard
            self._cv.notify_all()

    # -- what this peer accepts ---------------------------------------------------------------------
    def set_message_limit(self, limit):
        """``limit(phase, step)``: the most bytes a genuine ``phase`` message of ``step`` can have in
        this run (nodes/peer.py sizes it from the scene); longer ones are dropped unread, and each
        source may have 4 such messages' worth waiting at once."""
        self._message_limit = limit

    def message_limit(self, phase: str, step: int) -> int:
        if self._message_limit is None:
            return wire.MAX_MESSAGE
        return min(wire.MAX_MESSAGE, int(self._message_limit(phase, step)))

    def at_step(self, step: int):
        """This peer is at ``step``: messages of earlier steps are replays, and those more than the
        step window ahead are not from a peer of this run (``wait`` moves it on as well)."""
        with self._cv:
            self._mail.advance(step)

    # -- the transport interface ------------------------------------------------------------------
    def send(self, dest: int, tag: tuple, arrays: dict):
        step, phase = tag
        if phase == RESEND:
            raise ValueError(f"phase {RESEND!r} is the transport's own")
        self._serve_requests()
        payload = wire.encode(self.run, step, phase, self.rank, dest, arrays)
        if step > self._sent_step:  # what a neighbour can no longer ask for is let go
            self._sent_step = step
            for key in [k for k in self._sent if k[1] < step - KEEP_STEPS]:
                del self._sent[key]
                self._served.pop(key, None)
        self._sent[(dest, step, phase)] = payload
        self._put(dest, payload)
        self.bytes_sent[phase] = self.bytes_sent.get(phase, 0) + len(payload)

    def _put(self, dest: int, payload: bytes):
        """Hand ``payload`` to Zenoh for peer ``dest``: reliable, and blocking while the link is congested."""
        pub = self._publishers.get(dest)
        if pub is None:
            pub = self.session.declare_publisher(wire.halo_key(self.run, dest, self.rank),
                                                 congestion_control=self._zenoh.CongestionControl.BLOCK,
                                                 reliability=self._zenoh.Reliability.RELIABLE)
            self._publishers[dest] = pub
        pub.put(payload)

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
        payload = wire.encode(self.run, step, phase, self.rank, wire.VIEWER, arrays)
        if reliable:
            self.session.put(wire.frame_key(self.run, self.rank), payload,
                             congestion_control=self._zenoh.CongestionControl.BLOCK)
        else:
            self._frame_publisher().put(payload)
        self.bytes_sent["frames"] = self.bytes_sent.get("frames", 0) + len(payload)

    def recv(self, source: int, tag: tuple, check=None, patient: bool = False):
        """Generator with the in-process interface; it blocks instead of yielding."""
        return self.wait(source, tag, check, patient)
        yield  # pragma: no cover

    def wait(self, source: int, tag: tuple, check=None, patient: bool = False) -> dict:
        """The first message ``tag`` from ``source`` that ``check`` (if given) does not reject;
        rejected ones are dropped and counted. Raises PeerLost when a peer leaves, PeerTimeout after
        ``timeout`` seconds; warns while the source is connected but silent (unless ``patient``: a
        held run) and asks it to send the message again."""
        step, phase = tag
        key = (source, step, phase)
        t0 = time.monotonic()
        while True:
            arrays = self._next_candidate(key, t0, patient)
            try:
                if check is not None:
                    check(arrays)
            except Reject as r:
                self._drops(source, r.reason, f"step {step} {phase!r}: {r.detail}")
                continue
            with self._cv:
                self._mail.delivered(key)
                asked = self._asked.get(key, 0)
            waited = time.monotonic() - t0
            if asked and not patient:  # lost and sent again, or not sent yet: the sender's log says which
                log.warning("peer %d, step %d: peer %d's %r message came after %.1f s and %d request%s to send it "
                            "again", self.rank, step, source, phase, waited, asked, "s" * (asked != 1))
            self._usual_wait[source] = 0.9 * self._usual_wait.get(source, 0.0) + 0.1 * waited
            self.wait_s[phase] = self.wait_s.get(phase, 0.0) + waited
            return arrays

    def _next_candidate(self, key, t0, patient=False):
        """Block until a message is filed under ``key`` (or the wait is over) and take it."""
        source, step, phase = key
        deadline = t0 + self.timeout
        # a peer that is merely as slow as usual (e.g. compiling) is not worth a warning
        warn_at = max(self.not_answering_s, 10.0 * self._usual_wait.get(source, 0.0))
        with self._cv:
            self._mail.advance(step)
        while True:
            self._serve_requests()  # the peer we wait for may wait for a message of ours again
            ask = False
            with self._cv:
                arrays = self._mail.pop(key)
                if arrays is not None:
                    return arrays
                if phase != "bye" or source in self._lost:  # at the end, peers that got their bye leave
                    self._check_lost(step, phase)
                now = time.monotonic()
                quiet = now - max(t0, self._heard.get(source, t0))
                if quiet >= warn_at and source in self._alive:
                    if not patient:  # a held run waits for rank 0 as long as it is held: nothing to report
                        log.warning("peer %d, step %d: peer %d not answering for %.1f s (still connected); waiting "
                                    "for its %r message, asked it to send that again", self.rank, step, source, quiet,
                                    phase)
                    warn_at *= 2
                    ask = True  # (a held run's message can be lost too)
                left = deadline - now
                if left <= 0:
                    state = (f"peer {source} not answering for {quiet:.1f} s (still connected: its process is busy, "
                             "hung or stuck)" if source in self._alive else f"peer {source} not connected")
                    # what did come from it: a message under another tag, or drops, tell a lost message
                    # from a peer that never got that far
                    drops = self._drops.counts.get(str(source), {})
                    dropped = ", ".join(f"{n} {reason}" for reason, n in sorted(drops.items())) or "none"
                    asked = self._asked.get(key, 0)
                    raise PeerTimeout(f"peer {self.rank}, step {step}: no {phase!r} message from peer {source} "
                                      f"after {self.timeout:g} s: {state} (from peer {source}: "
                                      f"{self._mail.account(source)}; dropped: {dropped}); asked it for that "
                                      f"message again {asked} time{'s' * (asked != 1)}")
                if not ask and not self._requests:
                    self._cv.wait(max(0.01, min(left, 0.5, warn_at - quiet)))
            if ask:
                self._ask_again(source, step, phase)

    def _check_lost(self, step, phase):
        if self._lost:
            lost = "; ".join(self._lost_reason(r) for r in sorted(self._lost))
            raise PeerLost(f"peer {self.rank}, step {step} ({phase}): {lost}")

    def _lost_reason(self, rank: int) -> str:
        """Why ``rank``'s token vanished, as far as this peer can tell: a process that ends closes
        its links at once, while one that is stopped (SIGSTOP), hung or cut off goes quiet first and
        its link times out a lease later."""
        silent = self._lost[rank]
        if silent is not None and silent >= SILENT_FRACTION * self.lease_s:
            return (f"peer {rank} not answering for {silent:.1f} s, then its link timed out (the process is "
                    "stopped or hung, or its machine or network is down; it did not exit)")
        return f"peer {rank} left the run (process ended or its network link was lost)"

    def check(self):
        """Raise PeerLost if a peer of the run has gone (called between steps)."""
        with self._cv:
            self._check_lost(-1, "between steps")

    def idle(self, seconds: float):
        """Generator with the in-process interface; it sleeps instead of yielding."""
        time.sleep(seconds)
        return
        yield  # pragma: no cover

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
        while True:
            self._serve_requests()  # a peer whose "bye" was lost asks for it again
            with self._cv:
                if not self._alive - {self.rank}:
                    return
                left = deadline - time.perf_counter()
                if left <= 0:
                    log.warning("peer %d: peers %s still connected %g s after the end of the run", self.rank,
                                sorted(self._alive - {self.rank}), timeout)
                    return
                if not self._requests:
                    self._cv.wait(min(left, 0.5))

    def close(self):
        with self._cv:
            self._closing = True
        try:
            self._token.undeclare()
            self.session.close()
        except Exception as e:  # closing must not hide the error that brought us here
            log.debug("peer %d: zenoh close: %s", self.rank, e)
