"""The wire format and the Zenoh endpoint: framing, validation, delivery, timeouts, lost peers,
and what an endpoint refuses (wrong key, step window, bounds, duplicates, the receiver's check).

Zenoh runs on loopback only, with multicast scouting off and explicit endpoints.
"""
import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from launch.local import free_ports
from nodes import transport, wire
from nodes.zenoh_transport import PeerLost, PeerTimeout, ZenohEndpoint
from sphcore.halo import Reject

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.fast
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
@pytest.mark.fast
def test_wire_rejects_malformed_and_foreign_messages(mutate, fragment):
    data = wire.encode("run-1", 3, "fields", 1, 0, {"x": np.zeros((2, 3))})
    with pytest.raises(wire.WireError, match=fragment.replace(".", r"\.").replace("(", r"\(")):
        wire.decode(mutate(data), "run-1", 0, 3)


@pytest.mark.fast
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
    b.send(0, (5, "fields"), {"x": x[:3]})  # a message under another tag: the report names it
    deadline = time.time() + 5  # it must have arrived before the wait starts, or the silence is shorter
    while time.time() < deadline:
        with a._cv:
            if "5 'fields'" in a._mail.account(1):
                break
        time.sleep(0.01)
    with pytest.raises(PeerTimeout, match=r"peer 0, step 5: no 'positions' message from peer 1 after 3 s: "
                                          r"peer 1 not answering for 3\.\d s \(still connected") as timeout:
        a.wait(1, (5, "positions"))  # the foreign run's message never reached us
    assert "(from peer 1: waiting unread: 5 'fields'; taken this step: none; dropped: none)" in str(timeout.value)
    assert b.drops == {"0": {"foreign": 1, "malformed": 1}}


def test_a_peer_that_leaves_is_noticed_at_once(pair):
    a, b, _ = pair
    a.timeout = 30
    b.close()
    t0 = time.perf_counter()
    with pytest.raises(PeerLost, match="peer 1 left the run"):
        a.wait(1, (0, "fields"))
    assert time.perf_counter() - t0 < 2.0


# -- decode never raises anything but WireError, whatever the bytes ---------------------------------
def _header_of(data):
    hlen = int.from_bytes(data[6:10], "little")
    return json.loads(data[10:10 + hlen]), data[10 + hlen:]


def _framed(head, body: bytes = b"") -> bytes:
    raw = head if isinstance(head, bytes) else json.dumps(head).encode()
    return b"SPHW" + (1).to_bytes(2, "little") + len(raw).to_bytes(4, "little") + raw + body


def _decode_or_wire_error(data):
    """decode's result, or the WireError it raised; any other exception fails the test."""
    try:
        return wire.decode(data, "run-1", 0, 3)
    except wire.WireError as e:
        assert e.reason in ("oversized", "malformed", "foreign", "wrong source"), e.reason
        return e


@pytest.mark.fast
def test_decode_of_random_truncated_and_mutated_bytes_raises_only_wire_error():
    # Given a genuine message and a seeded stream of damage: truncation, byte flips, insertions,
    # random bytes, and headers whose fields hold values of every JSON type
    rng = np.random.default_rng(16)
    good = wire.encode("run-1", 3, "fields", 1, 0,
                       {"x": rng.random((4, 3)), "id": np.arange(4), "f": np.ones(2, np.uint8)})
    head, body = _header_of(good)
    values = [None, True, False, 0, -1, 1, 2 ** 70, 1.5, float("nan"), "", "x" * 100, "run-1", [], [1], [[1]],
              {}, {"a": 1}, [["x", "<f8", [4, 3]]], [["x", "<f8", [True, 3]]], [["x", "<f8", 4]],
              [["x", "<f8", [4, 3], 1]], [[1, "<f8", [4]]], [["x", "|O", [1]]]]
    outcomes = {"decoded": 0, "refused": 0}
    for i in range(3000):
        kind = i % 5
        if kind == 0:
            data = good[:rng.integers(0, len(good))]
        elif kind == 1:
            data = bytearray(good)
            for at in rng.integers(0, len(good), size=rng.integers(1, 8)):
                data[at] = rng.integers(0, 256)
            data = bytes(data)
        elif kind == 2:
            at = rng.integers(0, len(good))
            data = good[:at] + rng.bytes(int(rng.integers(1, 64))) + good[at:]
        elif kind == 3:
            data = rng.bytes(int(rng.integers(0, 200)))
            if rng.random() < 0.5:
                data = b"SPHW\x01\x00" + data
        else:
            changed = json.loads(json.dumps(head))
            if rng.random() < 0.5:  # a header field, or one part of one entry of the array table
                changed[list(head)[rng.integers(0, len(head))]] = values[rng.integers(0, len(values))]
            else:
                entry = changed["arrays"][rng.integers(0, len(changed["arrays"]))]
                entry[rng.integers(0, 3)] = values[rng.integers(0, len(values))]
            if rng.random() < 0.2:
                changed["extra"] = 1
            data = _framed(changed, body)
        # When it is decoded
        result = _decode_or_wire_error(data)
        # Then it is either a complete message whose arrays fill it exactly, or a WireError
        if isinstance(result, wire.WireError):
            outcomes["refused"] += 1
        else:
            source, (step, phase), arrays = result
            assert isinstance(source, int) and isinstance(step, int) and not isinstance(step, bool)
            assert sum(a.nbytes for a in arrays.values()) <= len(data)
            outcomes["decoded"] += 1
    assert outcomes["refused"] > 2000 and outcomes["decoded"] > 0, outcomes  # both paths were exercised


@pytest.mark.fast
@pytest.mark.parametrize("where", ["arrays", "run", "phase", "top"])
def test_a_deeply_nested_60_kB_header_is_refused_before_the_json_parser_sees_it(where):
    # Given a 60 kB header nesting brackets 30,000 deep (json.loads would raise RecursionError)
    deep = "[" * 30000 + "]" * 30000
    fields = {"run": '"run-1"', "step": "3", "phase": '"fields"', "source": "1", "dest": "0", "arrays": "[]"}
    if where == "top":
        raw = deep.encode()
    else:
        fields[where] = deep
        raw = ("{" + ",".join(f'"{k}":{v}' for k, v in fields.items()) + "}").encode()
    assert len(raw) > 59_000
    # When it is decoded, Then it is a WireError about the nesting, quickly
    t0 = time.perf_counter()
    with pytest.raises(wire.WireError, match="nests brackets deeper than 4"):
        wire.decode(_framed(raw), "run-1", 0, 3)
    assert time.perf_counter() - t0 < 0.5


@pytest.mark.fast
def test_brackets_inside_strings_do_not_count_as_nesting_and_the_schema_is_exact():
    data = wire.encode("run-1", 3, "fields", 1, 0, {"x": np.zeros((2, 3))})
    head, body = _header_of(data)
    # brackets inside a string are text, not nesting: refused for the run, not for the brackets
    with pytest.raises(wire.WireError, match="message of run") as e:
        wire.decode(_framed(dict(head, run="[[[[[[[[" * 100), body), "run-1", 0, 3)
    assert e.value.reason == "foreign"
    cases = [(dict(head, step=True), "bad step"), (dict(head, source=True), "source rank True"),
             (dict(head, dest=False), "for peer False"), (dict(head, extra=1), "header fields"),
             ({k: v for k, v in head.items() if k != "dest"}, "header fields"),
             (dict(head, step=2 ** 60), "bad step"), (dict(head, arrays=[["x", "<f8", [2, 3]]] * 65), "65 arrays"),
             (dict(head, arrays=[["x", "<f8", [2, 3], 0]]), "bad array entry"), ([1, 2], "not an object")]
    for changed, fragment in cases:
        with pytest.raises(wire.WireError, match=fragment.replace("(", r"\(")):
            wire.decode(_framed(changed, body), "run-1", 0, 3)


@pytest.mark.fast
def test_a_message_over_the_size_cap_is_refused_before_parsing():
    data = wire.encode("run-1", 3, "fields", 1, 0, {"x": np.zeros(1000)})
    with pytest.raises(wire.WireError, match="exceeds the limit of 1000 bytes") as e:
        wire.decode(data, "run-1", 0, 3, max_bytes=1000)
    assert e.value.reason == "oversized"
    assert wire.decode(data, "run-1", 0, 3, max_bytes=len(data))[0] == 1


# -- what an endpoint files and what it drops -------------------------------------------------------
def _until(condition, timeout=5.0):
    deadline = time.time() + timeout
    while not condition() and time.time() < deadline:
        time.sleep(0.01)
    return condition()


def test_the_source_in_the_header_must_be_the_source_the_key_names(pair):
    a, b, _ = pair
    # peer 0 publishes a message that says it is from peer 0 on a key that says peer 5 (not a rank of this run)
    a.session.put("sph/pair/halo/1/5", wire.encode("pair", 0, "fields", 0, 1, {}))
    a.session.put("sph/pair/halo/1/1", wire.encode("pair", 0, "fields", 0, 1, {}))  # b's own key, not a's
    assert _until(lambda: b.dropped == 2)
    assert b.drops == {"other": {"wrong key": 1}, "1": {"wrong key": 1}}
    assert (0, 0, "fields") not in b._mail


def test_the_step_window_duplicates_and_bounds_of_the_mailbox(pair):
    a, b, _ = pair
    b.at_step(10)
    # Given messages from peer 0: a replay (step 9), one too far ahead (13), two fine, a copy, a flood
    a.send(1, (9, "fields"), {"x": np.zeros(2)})
    a.send(1, (13, "fields"), {"x": np.zeros(2)})
    a.send(1, (12, "fields"), {"x": np.zeros(2)})
    a.send(1, (12, "fields"), {"x": np.zeros(2)})           # the same bytes again: a duplicate
    for i in range(transport.MAX_CANDIDATES + 1):            # different messages under one key
        a.send(1, (11, "fields"), {"x": np.full(2, float(i))})
    held = 1 + transport.MAX_CANDIDATES                       # step 12's and step 11's wait now
    for i in range(transport.MAX_PENDING):                    # the per-source bound: the last `held` are refused
        a.send(1, (10, f"p{i}"), {})
    expected = {"old step": 1, "future step": 1, "duplicate": 1, "inbox full": 1 + held}
    assert _until(lambda: b.dropped == sum(expected.values())), b.drops
    assert b.drops == {"0": expected}
    # When the receiver takes step 11 with a check that refuses the first two candidates
    seen = []

    def check(arrays):
        seen.append(float(arrays["x"][0]))
        if arrays["x"][0] < 2:
            raise Reject("count", "not this one")

    got = b.wait(0, (11, "fields"), check)
    # Then it gets the third, the two before are counted as rejected, the one after as a duplicate
    assert seen == [0.0, 1.0, 2.0] and got["x"][0] == 2.0
    # (a timeout's report lists what waits from peer 0 and what was taken: step 10's flood is freed)
    assert b._mail.account(0) == "waiting unread: 12 'fields'; taken this step: 11 'fields'"
    counts = b.drops["0"]
    assert counts["count"] == 2 and counts["duplicate"] == 2
    a.send(1, (11, "fields"), {"x": np.full(2, 9.0)})         # after delivery: a duplicate too
    assert _until(lambda: b.drops["0"]["duplicate"] == 3)
    # And moving to step 12 frees what was never asked for (the step 10 flood), counted as unused
    b.at_step(12)
    assert b.drops["0"]["unused"] == transport.MAX_PENDING - held
    assert b.wait(0, (12, "fields"))["x"].tolist() == [0.0, 0.0]


def test_a_message_longer_than_the_runs_largest_is_dropped_unread(pair):
    a, b, _ = pair
    b.set_message_limit(lambda phase, step: 2000 if phase == "final" else 500)
    a.send(1, (0, "fields"), {"x": np.zeros(100)})  # 800 bytes of array
    a.send(1, (0, "final"), {"x": np.zeros(100)})
    assert _until(lambda: (0, 0, "final") in b._mail)
    assert b.drops == {"0": {"oversized": 1}}


def test_drops_are_logged_at_most_once_per_reason_per_second(pair, caplog):
    a, b, _ = pair
    b.at_step(0)
    with caplog.at_level(logging.WARNING, logger="sph.zenoh"):
        for i in range(200):
            a.send(1, (100 + i, "fields"), {})
        assert _until(lambda: b.dropped == 200)
    lines = [r.getMessage() for r in caplog.records if "future step" in r.getMessage()]
    assert 1 <= len(lines) <= 2, lines  # 200 drops in well under 2 s
    assert b.drops == {"0": {"future step": 200}}


def test_a_connected_peer_that_sends_nothing_is_reported_as_not_answering(pair, caplog):
    a, b, _ = pair
    a.timeout, a.not_answering_s = 1.5, 0.4
    with caplog.at_level(logging.WARNING, logger="sph.zenoh"):
        with pytest.raises(PeerTimeout, match=r"peer 1 not answering for 1\.\d s \(still connected"):
            a.wait(1, (0, "fields"))
    assert any("peer 1 not answering for 0.4 s (still connected)" in r.getMessage() for r in caplog.records)


_TICKER = """
import sys
from nodes.zenoh_transport import ZenohEndpoint
ep = ZenohEndpoint("tick", 1, 2, [sys.argv[1]], [sys.argv[2]], timeout=60)
ep.wait_for_peers(30)
step = 0
while True:  # ping-pong with rank 0: tick, wait for tock
    ep.send(0, (step, "tick"), {})
    ep.wait(0, (step, "tock"))
    step += 1
"""


@pytest.mark.parametrize("how", ["SIGSTOP", "SIGKILL"])
def test_a_stopped_peer_is_told_from_one_that_ended(how, caplog):
    # Given rank 0 here and rank 1 in another process, exchanging a message every few milliseconds
    ports = free_ports(2)
    me = ZenohEndpoint("tick", 0, 2, [f"tcp/127.0.0.1:{ports[0]}"], [], timeout=30)
    child = subprocess.Popen([sys.executable, "-c", _TICKER, f"tcp/127.0.0.1:{ports[1]}",
                              f"tcp/127.0.0.1:{ports[0]}"], cwd=ROOT, start_new_session=True,
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        me.wait_for_peers(30)
        step = 0
        for step in range(20):
            me.wait(1, (step, "tick"))
            me.send(1, (step, "tock"), {})
        # its tick for step 20 follows our last tock at once: take it, so that the tick awaited below is
        # one it cannot have sent (it waits for a tock 20 that never comes) and the wait must end in PeerLost
        step += 1
        me.wait(1, (step, "tick"))
        # When it is stopped (or killed) while we wait for its next message
        os.kill(child.pid, getattr(signal, how))
        t0 = time.perf_counter()
        with caplog.at_level(logging.WARNING, logger="sph.zenoh"):
            with pytest.raises(PeerLost) as lost:
                me.wait(1, (step + 1, "tick"))
        elapsed = time.perf_counter() - t0
        text = str(lost.value)
        # Then a killed peer has left at once; a stopped one was "not answering (still connected)" first,
        # and is reported as not answering when its link times out a lease later, never as having left
        if how == "SIGKILL":
            assert "peer 1 left the run" in text and elapsed < 2.0, (text, elapsed)
        else:
            warned = [r.getMessage() for r in caplog.records if "not answering" in r.getMessage()]
            assert warned and "peer 1 not answering for 2.0 s (still connected)" in warned[0], warned
            assert "left the run" not in text and "then its link timed out" in text, text
            assert "peer 1 not answering for" in text and "it did not exit" in text
            assert 4.0 < elapsed < 9.0, elapsed
    finally:
        os.kill(child.pid, signal.SIGKILL)
        child.wait(10)
        me.close()


def test_a_mailbox_accounts_for_what_a_source_sent():
    box = transport.Mailbox(transport.DropLog("test"), window=None)
    assert box.account(3) == "waiting unread: none; taken this step: none"
    for step, phase in [(7, "fields"), (6, "moved"), (7, "lists"), (8, "moved")]:
        box.put(3, step, phase, {}, 10)
    box.put(4, 6, "moved", {}, 10)          # another source's: not listed
    box.pop((3, 6, "moved"))
    box.delivered((3, 6, "moved"))
    assert box.account(3, most=2) == "waiting unread: 7 'fields', 7 'lists' and 1 more; taken this step: 6 'moved'"


def _lose_first_put(endpoint):
    """``endpoint`` hands Zenoh nothing for its next message, as if the link lost it."""
    real, lost = endpoint._put, []

    def lossy(dest, payload):
        if not lost:
            lost.append(payload)
            return
        real(dest, payload)

    endpoint._put = lossy
    return lost


def test_a_lost_message_is_asked_for_again_and_taken_once(pair, caplog):
    a, b, _ = pair
    a.not_answering_s = b.not_answering_s = 0.3
    lost = _lose_first_put(a)
    got = {}

    def peer_1():
        got["fields"] = b.wait(0, (5, "fields"))
        b.send(0, (5, "ack"), {})

    # Given peer 0's message to peer 1 lost on the way, and peer 0 then waiting for peer 1's answer
    thread = threading.Thread(target=peer_1)
    thread.start()
    with caplog.at_level(logging.WARNING, logger="sph.zenoh"):
        a.send(1, (5, "fields"), {"x": np.arange(3.0)})
        a.wait(1, (5, "ack"))
    thread.join(5)
    # Then peer 1 asked for it again, peer 0 sent the same bytes again, and peer 1 took them
    assert len(lost) == 1 and got["fields"]["x"].tolist() == [0.0, 1.0, 2.0]
    assert b.resends == {"asked": {"0": 1}, "sent": {}} and a.resends["sent"] == {"1": 1}
    said = [r.getMessage() for r in caplog.records]
    assert "peer 0: peer 1 asked again for our 'fields' message of step 5; sending it again (1 of 3)" in said
    assert any(m.startswith("peer 1, step 5: peer 0's 'fields' message came after 0.") and
               m.endswith("and 1 request to send it again") for m in said), said
    # (peer 0's own request for peer 1's answer, not sent yet when it asked, was ignored: nothing dropped)
    assert a.drops == {} and b.drops == {}
    # And a copy that comes later (a request still on its way) is not a drop for the peer that asked
    a._put(1, lost[0])
    time.sleep(0.3)
    assert b.drops == {}


def test_requests_to_send_again_are_checked_and_bounded(pair):
    a, b, _ = pair
    a.send(1, (5, "fields"), {"x": np.zeros(2)})
    a.send(1, (6, "fields"), {"x": np.ones(2)})
    assert b.wait(0, (5, "fields"))["x"].tolist() == [0.0, 0.0]

    def ask(step, arrays):
        b._put(0, wire.encode("pair", step, "resend", 1, 0, arrays))

    def name(text):
        return {"phase": np.frombuffer(text.encode(), dtype=np.uint8)}

    # Given requests from peer 1: malformed ones, one for a message peer 0 never kept, and one asked 5 times
    ask(5, {})
    ask(5, {"phase": np.zeros(3)})
    ask(5, dict(name("fields"), y=np.zeros(1, np.uint8)))
    ask(5, name("no such!"))
    ask(5, name("x" * 33))
    ask(5, name("resend"))
    ask(1, name("fields"))                                   # older than the steps peer 0 keeps
    ask(7, name("fields"))                                   # not sent yet: left to come
    for _ in range(5):
        ask(6, name("fields"))
    assert _until(lambda: len(a._requests) == 7), a.drops
    # When peer 0 next sends or waits
    a._serve_requests()
    # Then only the genuine request was served, 3 times at most; the rest were counted as drops
    assert a.drops == {"1": {"malformed": 6, "resend unknown": 1, "resend limit": 2}}
    assert a.resends["sent"] == {"1": 3}
    assert b.wait(0, (6, "fields"))["x"].tolist() == [1.0, 1.0]
    # (peer 1 did not ask for those copies: beyond the one it took, they are duplicates it counts)
    assert _until(lambda: b.drops.get("0", {}).get("duplicate", 0) == 3), b.drops
    with pytest.raises(ValueError, match="resend"):
        a.send(1, (7, "resend"), {})


def test_a_patient_wait_says_nothing_but_still_asks_again(pair, caplog):
    a, b, _ = pair
    a.timeout, a.not_answering_s = 1.5, 0.3
    # Given a peer held by rank 0 (a patient wait: the run is paused as long as rank 0 says)
    with caplog.at_level(logging.WARNING, logger="sph.zenoh"):
        with pytest.raises(PeerTimeout):
            a.wait(1, (4, "hold0"), patient=True)
    # Then it never reported the source as not answering, yet asked it for the message again
    assert not [r for r in caplog.records if "not answering" in r.getMessage()]
    assert a.resends["asked"]["1"] >= 2
    assert _until(lambda: len(b._requests) >= 2) and b._requests[0] == (0, 4, "hold0")
