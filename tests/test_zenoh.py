"""The wire format and the Zenoh endpoint: framing, validation, delivery, timeouts, lost peers.

Zenoh runs on loopback only, with multicast scouting off and explicit endpoints.
"""
import json
import time

import numpy as np
import pytest

from launch.local import free_ports
from nodes import wire
from nodes.zenoh_transport import PeerLost, PeerTimeout, ZenohEndpoint


def test_wire_round_trip_keeps_names_dtypes_shapes_and_bytes():
    arrays = {"id": np.arange(5, dtype=np.int64), "x": np.random.default_rng(0).random((5, 3)),
              "rho": np.ones(5, dtype=np.float32), "empty": np.zeros((0, 3)), "flag": np.array([1, 0], np.uint8)}
    data = wire.encode("run-1", 7, "positions", 2, 0, arrays)
    source, tag, got = wire.decode(data, "run-1", 0, 3)
    assert (source, tag) == (2, (7, "positions"))
    assert list(got) == list(arrays)
    for k, a in arrays.items():
        assert got[k].dtype == a.dtype.newbyteorder("<") and got[k].shape == a.shape and np.array_equal(got[k], a)


def _corrupt_header(data, **changes):
    """Rebuild ``data`` with header fields changed (a well-framed but wrong message)."""
    hlen = int.from_bytes(data[6:10], "little")
    head = json.loads(data[10:10 + hlen])
    head.update(changes)
    new = json.dumps(head).encode()
    return data[:6] + len(new).to_bytes(4, "little") + new + data[10 + hlen:]


@pytest.mark.parametrize("mutate, fragment", [
    (lambda d: d[:8], "shorter than"),
    (lambda d: b"XXXX" + d[4:], "magic"),
    (lambda d: d[:4] + (9).to_bytes(2, "little") + d[6:], "version 9"),
    (lambda d: d[:6] + (10**6).to_bytes(4, "little") + d[10:], "header length"),
    (lambda d: d + b"\0", "left over"),
    (lambda d: d[:-1], "past the end"),
    (lambda d: _corrupt_header(d, run="other"), "run 'other'"),
    (lambda d: _corrupt_header(d, dest=2), "for peer 2"),
    (lambda d: _corrupt_header(d, source=7), "source rank 7"),
    (lambda d: _corrupt_header(d, source=0), "source rank 0"),
    (lambda d: _corrupt_header(d, phase="../x"), "phase"),
    (lambda d: _corrupt_header(d, arrays=[["x", "|O", [2, 3]]]), "dtype"),
    (lambda d: _corrupt_header(d, arrays=[["x", "<f8", [-2, 3]]]), "shape"),
    (lambda d: _corrupt_header(d, arrays="x"), "not a list"),
    (lambda d: d[:10] + b"}" + d[11:], "unreadable header"),
    (lambda d: d[:10] + b"[" + d[11:], "unreadable header"),
])
def test_wire_rejects_malformed_and_foreign_messages(mutate, fragment):
    data = wire.encode("run-1", 3, "fields", 1, 0, {"x": np.zeros((2, 3))})
    with pytest.raises(wire.WireError, match=fragment.replace(".", r"\.").replace("(", r"\(")):
        wire.decode(mutate(data), "run-1", 0, 3)


def test_run_ids_must_be_safe_key_segments():
    assert wire.check_run_id("abc-123_x") == "abc-123_x"
    for bad in ("", "a/b", "a*", "x" * 65, "a b"):
        with pytest.raises(ValueError):
            wire.check_run_id(bad)


@pytest.fixture
def pair():
    """Two endpoints of a 2-peer run (and a third of another run on the same network)."""
    ports = free_ports(3)
    ep = [f"tcp/127.0.0.1:{p}" for p in ports]
    a = ZenohEndpoint("pair", 0, 2, [ep[0]], [], timeout=3)
    b = ZenohEndpoint("pair", 1, 2, [ep[1]], [ep[0]], timeout=3)
    foreign = ZenohEndpoint("other", 1, 2, [ep[2]], [ep[0], ep[1]], timeout=3)
    a.wait_for_peers(10)
    b.wait_for_peers(10)
    yield a, b, foreign
    for e in (foreign, b, a):
        e.close()


def test_endpoints_deliver_by_source_and_tag_and_drop_foreign_or_malformed(pair):
    a, b, foreign = pair
    x = np.random.default_rng(1).random((1000, 3))
    a.send(1, (5, "positions"), {"x": x})
    foreign.send(0, (5, "positions"), {"x": np.zeros((1, 3))})   # another run: other key space
    foreign.session.put(wire.halo_key("pair", 1, 0), b"not a message")  # garbage on our inbox
    a.session.put(wire.halo_key("pair", 1, 0), wire.encode("pair", 6, "fields", 0, 0, {}))  # wrong dest
    got = b.wait(0, (5, "positions"))
    assert np.array_equal(got["x"], x)
    deadline = time.time() + 5
    while b.dropped < 2 and time.time() < deadline:
        time.sleep(0.01)
    assert b.dropped == 2
    assert a.bytes_sent["positions"] > x.nbytes
    with pytest.raises(PeerTimeout, match=r"peer 0, step 5: no 'positions' message from peer 1 \(alive\)"):
        a.wait(1, (5, "positions"))  # the foreign run's message never reached us


def test_a_peer_that_leaves_is_noticed_at_once(pair):
    a, b, _ = pair
    a.timeout = 30
    b.close()
    t0 = time.perf_counter()
    with pytest.raises(PeerLost, match="peer 1 left the run"):
        a.wait(1, (0, "fields"))
    assert time.perf_counter() - t0 < 2.0
