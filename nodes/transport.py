"""Transports that move a peer's halo messages (dicts of numpy arrays) to another peer.

Interface used by ``sphcore.halo.PeerHalo`` (one endpoint per peer):

    send(dest: int, tag: tuple, arrays: dict[str, np.ndarray]) -> None
    recv(source: int, tag: tuple) -> generator; yields while waiting, returns the arrays

``InProcessNetwork`` connects the peers of one process (tests, and checking that N peers give the
same bits as one); a Zenoh transport with the same interface carries them between processes.
"""
from __future__ import annotations


class InProcessNetwork:
    """Mailboxes in memory, one per (receiver, sender, tag). Arrays are copied on send, as they
    would be on a wire."""

    def __init__(self):
        self._mail = {}

    def endpoint(self, rank: int) -> "InProcessEndpoint":
        return InProcessEndpoint(self, rank)


class InProcessEndpoint:
    def __init__(self, network: InProcessNetwork, rank: int):
        self.network = network
        self.rank = rank

    def send(self, dest: int, tag: tuple, arrays: dict):
        key = (dest, self.rank, tag)
        if key in self.network._mail:
            raise RuntimeError(f"peer {self.rank}: message {tag} for peer {dest} sent twice")
        self.network._mail[key] = {k: v.copy() for k, v in arrays.items()}

    def recv(self, source: int, tag: tuple):
        """Generator: yields until the message ``tag`` from ``source`` to this peer has arrived."""
        key = (self.rank, source, tag)
        while key not in self.network._mail:
            yield key
        return self.network._mail.pop(key)
