"""What a peer's run needs from its transport: the ``Endpoint`` protocol, and the errors it raises.

``nodes.driver.drive`` runs a peer over any ``Endpoint``; two implement it:

    nodes.transport.InProcessEndpoint   peers of one process (tests, the in-process cluster, and a
                                        single-process run as peer 0 of 1); ``recv`` yields while
                                        it waits, so a scheduler can resume the peers in turn
    nodes.zenoh_transport.ZenohEndpoint one peer process on Zenoh; ``recv`` blocks (never yields)

A new transport (MPI, say) implements every member below; tests/test_layering.py checks that each
implementation has them all with the same parameters. Every generator member may also block instead
of yielding, as the Zenoh endpoint does: the driver runs it with ``yield from`` either way.

A tag is (step, phase): ``step`` the sender's step number, ``phase`` a short name ("positions",
"reduce", "ckpt", "final", "bye", ...). Arrays are {name: numpy array}; nothing else travels.
"""
from __future__ import annotations

from typing import Callable, Protocol

from sphcore.halo import Transport


class TransportError(RuntimeError):
    """The run cannot go on over this transport (``sph`` exits with the peer-lost code)."""


class PeerLost(TransportError):
    """A peer of the run has gone: its process ended, or its link timed out."""


class PeerTimeout(TransportError):
    """A peer did not send what was waited for (or did not join) within the endpoint's timeout."""


class Endpoint(Transport, Protocol):
    """One peer's end of the run's transport (``send``, ``recv`` and ``drops`` are the halo's, from
    ``sphcore.halo.Transport``)."""

    rank: int
    """This peer's rank."""
    bytes_sent: dict
    """{phase: bytes} this endpoint has sent so far (for summary.json); "frames" for the viewer's."""
    wait_s: dict
    """{phase: seconds} spent waiting in ``recv`` so far (0 for an endpoint that never blocks)."""

    def send(self, dest: int, tag: tuple, arrays: dict) -> None:
        """Send ``arrays`` to peer ``dest`` under ``tag``; returns once they are handed to the
        transport (the arrays may be reused). May block while the link is congested; raises
        ``RuntimeError`` if the in-process endpoint already holds an unreceived message under ``tag``."""

    def recv(self, source: int, tag: tuple, check: Callable[[dict], None] | None = None, patient: bool = False):
        """Generator returning the first message ``tag`` from ``source`` for which ``check(arrays)``
        does not raise ``sphcore.halo.Reject`` (rejected ones are dropped and counted in ``drops``).
        Yields (in-process) or blocks (between processes) until it arrives; raises ``PeerLost`` when
        a peer of the run has gone and ``PeerTimeout`` after the endpoint's timeout. ``patient``: a
        long wait is expected (a held run waits for rank 0): no warning that the source is not
        answering (it is still asked to send the message again, quietly)."""

    @property
    def drops(self) -> dict:
        """Messages dropped so far, never used: {source: {reason: count}} (a copy)."""

    @property
    def dropped(self) -> int:
        """How many messages were dropped so far (the sum of ``drops``)."""

    @property
    def resends(self) -> dict:
        """{"asked": {source: n}, "sent": {dest: n}}: how often this peer asked a silent peer for a
        message again, and sent one of its own again when asked (empty where nothing is lost)."""

    def at_step(self, step: int) -> None:
        """This peer is at ``step``: messages for earlier steps are replays and are dropped, as are
        those too far ahead. Never blocks."""

    def set_message_limit(self, limit: Callable[[str, int], int]) -> None:
        """``limit(phase, step)``: the most bytes a genuine message can have in this run; longer
        ones are dropped unread. Never blocks."""

    def wait_for_peers(self, timeout: float | None = None) -> None:
        """Block until every peer of the run can receive (its inbox exists); raises ``PeerTimeout``
        naming the missing peers after ``timeout`` seconds, ``PeerLost`` if one left meanwhile."""

    def check(self) -> None:
        """Raise ``PeerLost`` if a peer of the run has gone (called between steps); never blocks."""

    def idle(self, seconds: float):
        """Generator: let about ``seconds`` pass while this peer waits for something other than a
        message (rank 0 in a pause, polling for commands). Sleeps (between processes) or yields
        once (in-process). Raises nothing."""

    def take_commands(self) -> list:
        """Rank 0: the control commands received since the last call, as {"id", "text"}, oldest
        first (nodes/control.py validates them). Never blocks; other ranks get []."""

    def send_ack(self, command_id: str, result: str, step: int, reason: str = "") -> None:
        """Rank 0: tell the controller that command ``command_id`` was "accepted" (applied after
        ``step`` on every peer) or "rejected" (with ``reason``). May block while congested."""

    def viewer_listening(self) -> bool:
        """Whether a viewer subscribes to this peer's framelets (peers render only then); never blocks."""

    def publish_frame(self, step: int, phase: str, arrays: dict, reliable: bool = False) -> None:
        """Publish a framelet (phase "frame") or the end of the run ("end") to any viewer.
        Unreliable framelets are dropped rather than wait on a congested link; ``reliable`` ones
        may block."""

    def wait_until_alone(self, timeout: float = 10.0) -> None:
        """Rank 0 at the end: block until the other peers have left (they leave once they have
        its "bye"), at most ``timeout`` seconds (then a warning); raises nothing."""

    def close(self) -> None:
        """Leave the run and free the transport; raises nothing (it runs while an error unwinds)."""
