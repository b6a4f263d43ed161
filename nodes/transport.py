"""Transports that move a peer's halo messages (dicts of numpy arrays) to another peer, and the
mailbox every receiver files them in.

Every endpoint implements ``nodes.endpoint.Endpoint`` (the halo's part of it is
``sphcore.halo.Transport``: ``send``, ``recv``, ``drops``). ``check(arrays)`` is the receiver's
idea of what ``source`` must send under ``tag``; it raises ``sphcore.halo.Reject`` for anything
else. A rejected message is dropped and counted, and the receiver goes on waiting: a hostile
message that arrives first cannot stand in for, or block, the genuine one behind it.

``InProcessNetwork`` connects the peers of one process (tests, the in-process cluster, a
single-process run, and checking that N peers give the same bits as one); its endpoints' ``recv``
yields while it waits. ``nodes.zenoh_transport.ZenohEndpoint`` carries them between processes and
files what arrives in a ``Mailbox``: bounded (per source, per key, in bytes), inside a window of
steps around the receiver's own, with duplicates dropped.
"""
from __future__ import annotations

import logging
import threading
import time

from sphcore.halo import Reject

log = logging.getLogger("sph.transport")

STEP_WINDOW = 2        # a peer is at most one step ahead of another (every step ends in an all-to-all
                       # reduction); two leaves room, anything further ahead is not from this run's past
MAX_CANDIDATES = 4     # messages held per (source, step, phase) until the receiver takes one
MAX_PENDING = 64       # messages held per source (a genuine peer has a handful in flight)
LOG_INTERVAL_S = 1.0   # each drop reason is logged at most once per second


class DropLog:
    """Messages a receiver dropped, counted by source and reason; each reason is logged at most once
    per ``interval`` seconds (with the count of those not logged since), so a flood of hostile
    messages cannot flood the log too. Thread-safe (Zenoh's callbacks count here as well)."""

    def __init__(self, who: str, logger: logging.Logger = log, interval: float = LOG_INTERVAL_S):
        self.who, self.logger, self.interval = who, logger, interval
        self._counts = {}      # source label -> reason -> count
        self._said = {}        # reason -> monotonic time it was last logged
        self._unsaid = {}      # reason -> drops not logged since
        self._lock = threading.Lock()

    def __call__(self, source, reason: str, detail: str):
        label = str(source)
        with self._lock:
            by_reason = self._counts.setdefault(label, {})
            by_reason[reason] = by_reason.get(reason, 0) + 1
            now = time.monotonic()
            last = self._said.get(reason)
            if last is not None and now - last < self.interval:
                self._unsaid[reason] = self._unsaid.get(reason, 0) + 1
                return
            self._said[reason] = now
            unsaid = self._unsaid.pop(reason, 0)
        more = f" ({unsaid} more dropped for this reason since it was last logged)" if unsaid else ""
        self.logger.warning("%s: dropped a message from %s (%s): %s%s", self.who, label, reason, detail, more)

    @property
    def counts(self) -> dict:
        """{source: {reason: count}}, a copy."""
        with self._lock:
            return {s: dict(r) for s, r in self._counts.items()}

    @property
    def total(self) -> int:
        with self._lock:
            return sum(sum(r.values()) for r in self._counts.values())


class Mailbox:
    """Messages that arrived for one receiver and wait to be taken, keyed by (source, step, phase).

    Each key holds up to ``MAX_CANDIDATES`` different messages, oldest first; the receiver takes the
    first that passes its check (``pop`` then ``delivered``). Every source may have at most
    ``MAX_PENDING`` messages and a byte ``budget`` (given with each message) held at once. With a
    ``window``, a message for a step before the receiver's (``advance``) is a replay and one more
    than ``window`` steps ahead cannot come from a peer of this run; entries the receiver moved past
    without taking are freed. Every refusal goes to ``drop(source, reason, detail)``. Not
    thread-safe: the Zenoh endpoint calls it under its lock."""

    def __init__(self, drop: DropLog, window: int | None = STEP_WINDOW):
        self.drop = drop
        self.window = window
        self.step = None          # the receiver's step (None: not known yet, every step is let in)
        self._mail = {}           # (source, step, phase) -> [(arrays, size, raw), ...]
        self._taken = set()       # keys already delivered (so later copies are duplicates)
        self._held = {}           # source -> [messages, bytes]

    def put(self, source: int, step: int, phase: str, arrays: dict, size: int, raw: bytes | None = None,
            budget: int | None = None, asked: bool = False) -> bool:
        """File a message of ``size`` bytes (``raw``: its bytes, to tell a replayed copy); False if it
        was dropped. ``asked``: the receiver asked the source to send this message again, so a second
        copy, or one that comes after the receiver moved on, is expected and not counted as a drop."""
        what = f"step {step} {phase!r}"
        if self.step is not None and self.window is not None:
            if step < self.step:
                if not asked:
                    self.drop(source, "old step", f"{what}: this peer is at step {self.step} (a replay)")
                return False
            if step > self.step + self.window:
                self.drop(source, "future step", f"{what}: this peer is at step {self.step}, a peer of the run "
                                                 f"is never more than {self.window} ahead")
                return False
        key = (source, step, phase)
        if key in self._taken:
            if not asked:
                self.drop(source, "duplicate", f"{what}: already received")
            return False
        candidates = self._mail.get(key, [])
        if raw is not None and any(c[2] == raw for c in candidates):
            if not asked:
                self.drop(source, "duplicate", f"{what}: a copy of a message already waiting")
            return False
        held = self._held.setdefault(source, [0, 0])
        if len(candidates) >= MAX_CANDIDATES:
            self.drop(source, "inbox full", f"{what}: {MAX_CANDIDATES} messages already wait under this key")
            return False
        if held[0] >= MAX_PENDING or (budget is not None and held[1] + size > budget):
            self.drop(source, "inbox full", f"{what}: {held[0]} messages of {held[1]} bytes already wait from "
                                            f"this source (at most {MAX_PENDING}"
                                            + (f", {budget} bytes)" if budget is not None else ")"))
            return False
        self._mail.setdefault(key, []).append((arrays, size, raw))
        held[0] += 1
        held[1] += size
        return True

    def pop(self, key: tuple):
        """The oldest candidate under ``key`` (removed), or None."""
        candidates = self._mail.get(key)
        if not candidates:
            return None
        arrays, size, _ = candidates.pop(0)
        if not candidates:
            del self._mail[key]
        self._release(key[0], size)
        return arrays

    def delivered(self, key: tuple):
        """The receiver used a message of ``key``: the others waiting under it are duplicates."""
        for _ in self._mail.pop(key, []):
            self.drop(key[0], "duplicate", f"step {key[1]} {key[2]!r}: another message was already used")
        self._taken.add(key)

    def advance(self, step: int):
        """The receiver is at ``step``: free what it moved past (never taken, so counted as unused)."""
        if self.step is not None and step <= self.step:
            return
        self.step = step
        for key in [k for k in self._mail if k[1] < step]:
            for _, size, _ in self._mail.pop(key):
                self._release(key[0], size)
                self.drop(key[0], "unused", f"step {key[1]} {key[2]!r}: never asked for (now at step {step})")
        self._taken = {k for k in self._taken if k[1] >= step}

    def _release(self, source, size):
        held = self._held[source]
        held[0] -= 1
        held[1] -= size

    def __contains__(self, key) -> bool:
        return bool(self._mail.get(key))

    def account(self, source: int, most: int = 6) -> str:
        """What is filed from ``source`` and what was taken from it since the receiver's last step
        advance, as "(step, phase)" lists (at most ``most`` each): a timeout's report, which tells
        a message that never came from one that came under another tag."""
        def listed(keys):
            keys = sorted(keys)
            text = ", ".join(f"{step} {phase!r}" for step, phase in keys[:most])
            return (text + (f" and {len(keys) - most} more" if len(keys) > most else "")) or "none"
        waiting = [(k[1], k[2]) for k, c in self._mail.items() if k[0] == source and c]
        taken = [(k[1], k[2]) for k in self._taken if k[0] == source]
        return f"waiting unread: {listed(waiting)}; taken this step: {listed(taken)}"


class InProcessNetwork:
    """Mailboxes in memory, one per (receiver, sender, tag). Arrays are copied on send, as they
    would be on a wire. The peers of one process trust each other: no step window, no bounds."""

    def __init__(self):
        self._mail = {}    # (dest, source, tag) -> [arrays, ...]
        self._sent = set()  # keys sent by the endpoint itself and not yet received
        self.sends = 0      # messages sent so far (a scheduler's round without one is a deadlock)

    def endpoint(self, rank: int) -> "InProcessEndpoint":
        return InProcessEndpoint(self, rank)

    def deliver(self, dest: int, source: int, tag: tuple, arrays: dict):
        """Put a message in ``dest``'s mailbox as if ``source`` had sent it, ahead of or behind the
        genuine one (tests of what a receiver accepts)."""
        self._mail.setdefault((dest, source, tag), []).append(dict(arrays))


class CountsDrops:
    """What an endpoint dropped, from its ``_drops`` (a DropLog), and the messages it asked for again
    and sent again (``_asked_again``, ``_sent_again``: {rank: count}): the same views for every
    transport, so the peer's summary reads them alike."""

    @property
    def resends(self) -> dict:
        """{"asked": {source: n}, "sent": {dest: n}}: messages this peer asked a silent peer to send
        again, and messages it sent again when asked (nodes/zenoh_transport.py; none in memory, whose
        endpoints have neither tally)."""
        return {"asked": {str(k): v for k, v in sorted(getattr(self, "_asked_again", {}).items())},
                "sent": {str(k): v for k, v in sorted(getattr(self, "_sent_again", {}).items())}}

    @property
    def drops(self) -> dict:
        """Messages dropped so far: {source: {reason: count}} (source: a rank, "controller" or "other")."""
        return self._drops.counts

    @property
    def dropped(self) -> int:
        return self._drops.total


class InProcessEndpoint(CountsDrops):
    """Peer ``rank`` on an ``InProcessNetwork`` (``nodes.endpoint.Endpoint``). It never blocks:
    ``recv`` and ``idle`` yield, and a scheduler (nodes/cluster.py) resumes the peers in turn.
    Control commands are whatever a test puts in ``commands``; acknowledgements and published
    frames are kept in ``acks`` and ``frames``."""

    def __init__(self, network: InProcessNetwork, rank: int):
        self.network = network
        self.rank = rank
        self._drops = DropLog(f"peer {rank}")
        self.bytes_sent = {}      # phase -> array bytes sent (no headers in memory)
        self.wait_s = {}          # never blocks, so never waits
        self.commands = []        # rank 0: {"id", "text"} for take_commands
        self.acks = []            # (command_id, result, step, reason) from send_ack
        self.frames = []          # (step, phase) from publish_frame

    def send(self, dest: int, tag: tuple, arrays: dict):
        key = (dest, self.rank, tag)
        if key in self.network._sent:
            raise RuntimeError(f"peer {self.rank}: message {tag} for peer {dest} sent twice")
        self.network._sent.add(key)
        self.network.sends += 1
        self.network._mail.setdefault(key, []).append({k: v.copy() for k, v in arrays.items()})
        self._count(tag[1], arrays)

    def _count(self, phase: str, arrays: dict):
        self.bytes_sent[phase] = self.bytes_sent.get(phase, 0) + sum(int(a.nbytes) for a in arrays.values())

    def recv(self, source: int, tag: tuple, check=None, patient: bool = False):
        """Generator: yields until a message ``tag`` from ``source`` to this peer has arrived that
        passes ``check``; the ones that do not are dropped and counted (``patient``: nothing to say
        while waiting in memory)."""
        key = (self.rank, source, tag)
        while True:
            candidates = self.network._mail.get(key)
            while candidates:
                arrays = candidates.pop(0)
                try:
                    if check is not None:
                        check(arrays)
                except Reject as r:
                    self._drops(source, r.reason, f"step {tag[0]} {tag[1]!r}: {r.detail}")
                    continue
                for _ in candidates:
                    self._drops(source, "duplicate", f"step {tag[0]} {tag[1]!r}: another message was already used")
                del self.network._mail[key]
                self.network._sent.discard(key)
                return arrays
            yield key

    # -- the rest of nodes.endpoint.Endpoint: peers of one process trust each other and never block
    def at_step(self, step: int):
        """No step window in memory."""

    def set_message_limit(self, limit):
        """No size limit in memory."""

    def wait_for_peers(self, timeout: float | None = None):
        """Every peer of the network can receive from the start."""

    def check(self):
        """A peer of this process cannot be lost."""

    def idle(self, seconds: float):
        """Generator: yields once (the scheduler resumes the other peers meanwhile)."""
        yield ("idle", self.rank)

    def take_commands(self) -> list:
        out, self.commands = self.commands, []
        return out

    def send_ack(self, command_id: str, result: str, step: int, reason: str = ""):
        self.acks.append((command_id, result, step, reason))

    def viewer_listening(self) -> bool:
        """No viewer in memory: a single-process run hands its frames to its own Viewer."""
        return False

    def publish_frame(self, step: int, phase: str, arrays: dict, reliable: bool = False):
        self.frames.append((step, phase))
        self._count("frames", arrays)

    def wait_until_alone(self, timeout: float = 10.0):
        """Nothing is on its way in memory once it is sent."""

    def close(self):
        """Nothing to free."""
