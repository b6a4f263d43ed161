"""No message can crash or steer a peer.

A hostile sender (a Zenoh session on loopback that is not a peer of the run) publishes every kind
of message that crashed, stalled or changed a run before: a genuine message restamped to a future
step, a forged reduction that claims to be peer 1 on another key, one that carries a control
command, the wrong dtype, NaN positions, a wrong ghost count, a 60 kB deeply nested header, an
oversized message, 5,000 messages from the future, replays of old steps, and control commands on
keys that are not the controller's. The run must exit 0 with final.npz bitwise equal to an
undisturbed run, and summary.json must count every one of those messages by source and reason.

Without TLS (these runs are --insecure) anyone can publish on peer 1's key; only access control
(nodes/security.py) stops an outsider from doing so. What is checked here is everything a receiver
can tell by itself: the key, the step window, the bounds, and whether a message is what the
protocol says peer 1 sends at that step (a forgery that is consistent with the protocol on the
genuine key is what certificates are for, and is not sent here).

The checks themselves are also tested on in-process peers, where forged messages are put ahead of
the genuine ones deterministically.
"""
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from launch.cli import main
from launch.local import free_ports
from nodes import control, wire

from conftest import scene
from test_peers import Lines

ROOT = Path(__file__).resolve().parent.parent
# The energy watchdog off: its reference sum after step 1 (a reduction tagged step 1) moves peer 0's
# mailbox to step 1 while the run is held there, and the forged replay of step 0 that this test
# expects to be filed as a duplicate would then be an old step (run.energy_check_every, sphcore/health.py)
SCENE = ["configs/dam_break_2d.toml", "--set", "particles.spacing=0.01", "--precision", "f64",
         "--set", "run.energy_check_every=0",
         "--set", "run.neighbour_skin=0"]  # exchange 1 in full every step (reused lists: test_neighbour_skin.py)
STEPS = 1500  # long enough that the pause, sent after the first whole step is seen, comes before the end
# (400 were run through on a loaded machine while the controller was still connecting)


def peer_command(rank: int, world: int, run_id: str, ports: list[int], out: Path, steps: int = STEPS) -> list[str]:
    """The one place the test builds a peer's command line (TLS options go here)."""
    cmd = [sys.executable, "-m", "launch.cli", "peer", *SCENE, "--rank", str(rank), "--world", str(world),
           "--run-id", run_id, "--listen", f"tcp/127.0.0.1:{ports[rank]}", "--steps", str(steps),
           "--timeout", "120", "--threads", "1", "--no-frames", "--quiet", "--insecure"]
    for q in range(rank):
        cmd += ["--connect", f"tcp/127.0.0.1:{ports[q]}"]
    if rank == 0:
        cmd += ["--out", str(out)]
    return cmd


def start_run(run_id: str, out: Path, world: int = 2):
    """The peers' processes, their stderr as it comes (test_peers.Lines) and their endpoints."""
    ports = free_ports(world)
    procs = [subprocess.Popen(peer_command(r, world, run_id, ports, out), cwd=ROOT, text=True,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
             for r in range(world)]
    return procs, [Lines(p.stderr) for p in procs], [f"tcp/127.0.0.1:{p}" for p in ports]


def finish(procs, logs, timeout=120):
    """Every peer's (return code, stderr)."""
    results = []
    for p, log in zip(procs, logs):
        try:
            p.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
        results.append((p.returncode, log.text()))
    return results


class Attacker:
    """A Zenoh session connected to the peers that watches their halo traffic and publishes forged
    messages (to peer 0 unless said otherwise), counting what it sent to each peer."""

    def __init__(self, run_id: str, endpoints: list[str]):
        import zenoh
        from nodes.zenoh_transport import zenoh_config
        self.zenoh, self.run = zenoh, run_id
        conf = zenoh_config([], endpoints)
        # the peers may not listen yet: retry every 50 ms, so that we see their very first messages
        conf.insert_json5("connect/retry", json.dumps({"period_init_ms": 50, "period_max_ms": 50,
                                                        "period_increase_factor": 1}))
        self.session = zenoh.open(conf)
        self.sent = {0: 0, 1: 0}
        self.captured = {}          # (dest, source, step, phase) -> (payload, arrays)
        self.steps_seen = []        # steps of peer 0's reductions, as seen
        self.session.declare_subscriber(f"sph/{run_id}/halo/**", self._seen,
                                        allowed_origin=zenoh.Locality.REMOTE)  # the peers', not ours

    def _seen(self, sample):
        key = str(sample.key_expr).split("/")
        dest, source = int(key[-2]), int(key[-1])
        payload = sample.payload.to_bytes()
        try:
            _, (step, phase), arrays = wire.decode(payload, self.run, dest, 2)
        except wire.WireError:
            return
        self.captured[(dest, source, step, phase)] = (payload, arrays)
        if (dest, source, phase) == (1, 0, "reduce"):
            self.steps_seen.append(step)

    def wait_for_a_whole_step(self, timeout: float = 60.0) -> int:
        """The first step k of which this session saw peer 1's positions and fields to peer 0 and peer
        0's reduction to peer 1: a command sent now is accepted at step k + 1 or later (rank 0 sends
        the commands with its reduction), so the messages of the step before it are at hand to forge
        from. (The peers start without waiting for this session, and on a slow machine its
        subscription was not yet known to them during their first steps.)"""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            have = set(self.captured)
            for (dest, source, step, phase) in have:
                if (dest, source, phase) == (1, 0, "reduce") and {(0, 1, step, "positions"), (0, 1, step, "fields")} <= have:
                    return step
            time.sleep(0.01)
        raise AssertionError(f"the outsider saw no whole step in {timeout} s: {sorted(self.captured)[:20]}")

    def put(self, key: str, payload: bytes, dest: int = 0):
        self.session.put(key, payload, congestion_control=self.zenoh.CongestionControl.BLOCK)
        self.sent[dest] += 1

    def forge(self, step, phase, arrays, source=1, key_source=1):
        self.put(wire.halo_key(self.run, 0, key_source), wire.encode(self.run, step, phase, source, 0, arrays))

    def replay(self, dest: int, step: int):
        """A genuine message to ``dest`` of ``step``, sent again byte for byte."""
        payload, _ = self.captured[(dest, 1 - dest, step, "positions")]
        self.put(wire.halo_key(self.run, dest, 1 - dest), payload, dest)

    def latest(self, phase, before):
        """The newest genuine message peer 1 sent peer 0 under ``phase`` at a step <= ``before``."""
        steps = [k[2] for k in list(self.captured) if k[:2] == (0, 1) and k[3] == phase and k[2] <= before]
        return self.captured[(0, 1, max(steps), phase)] if steps else None

    def once(self, s):
        """The attacks that are dropped on arrival (peer 0 is at step s)."""
        nested = b"[" * 30000 + b"]" * 30000
        self.put(wire.halo_key(self.run, 0, 1), b"SPHW\x01\x00" + len(nested).to_bytes(4, "little") + nested)
        self.forge(s + 1, "fields", {"rho": np.zeros(400_000)})                      # 3.2 MB: oversized
        self.forge(s + 1, "reduce", {"stats": np.zeros(4)}, key_source=9)            # says peer 1, key says 9
        payload, arrays = self.latest("positions", s)
        self.forge(s + 50, "positions", arrays)                                      # restamped, far ahead
        self.forge(s + 2, "positions", arrays, key_source=9)                         # restamped, wrong key
        # a command on peer 1's key: nobody asks for a "control" message there; freed as unused
        self.forge(s + 2, "control", control.command_arrays(control.new_id(), "set forces.gravity=[0,9.81]"))
        command = control.command_arrays(control.new_id(), "pause")
        control_key = wire.control_key(self.run)
        self.put(control_key, wire.encode(self.run, -1, "control", 1, 0, command))  # not the controller
        self.put(control_key, wire.encode(self.run, -1, "control", wire.CONTROLLER, 0,
                                          {"id": np.frombuffer(b"XYZ", np.uint8), "command": command["command"]}))
        fields = self.latest("fields", s)[1]
        for i in range(5000):                                                        # the future flood
            self.forge(s + 100 + i, "fields", fields)

    def semantic(self, t):
        """Messages on peer 1's own key for step t that break the protocol, made from its last genuine
        ones: each must be dropped by peer 0's checks while the genuine one behind it is used."""
        _, ghosts = self.latest("positions", t - 1)
        _, fields = self.latest("fields", t - 1)
        wrong_dtype = dict(ghosts, x=ghosts["x"].astype(np.float32))
        n = len(ghosts["id"]) + 3
        nan = {k: np.resize(a, (n,) + a.shape[1:]) for k, a in ghosts.items()}
        nan["id"] = np.arange(n, dtype=np.int64)
        nan["x"] = np.full((n, 3), np.nan)
        self.forge(t, "positions", wrong_dtype)                                      # dtype
        self.forge(t, "positions", nan)                                              # not finite
        self.forge(t, "fields", {k: np.resize(a, (len(a) + 1000,)) for k, a in fields.items()})  # count
        self.forge(t, "reduce", {"stats": np.zeros(4), "control": np.frombuffer(b'[{"op": "pause"}]', np.uint8)})
        if len(ghosts["id"]):  # a "migrant" that sits in peer 1's own block: not peer 0's to take
            self.forge(t, "migrants", {k: a[:1] for k, a in ghosts.items()})          # owner

    def close(self):
        self.session.close()


def drops_of(summary, rank):
    return summary["per_peer"][rank]["dropped"]


@pytest.fixture(scope="module")
def undisturbed(tmp_path_factory):
    out = tmp_path_factory.mktemp("undisturbed")
    procs, logs, _ = start_run("calm", out)
    results = finish(procs, logs)
    assert [rc for rc, _ in results] == [0, 0], results
    return out


def _control(capsys, endpoint, run_id, *words, timeout="10"):
    """``sph control`` in this process: (exit code, what it printed)."""
    rc = main(["control", "--run-id", run_id, "--zenoh", endpoint, "--timeout", timeout, "--insecure", *words])
    return rc, capsys.readouterr().err


def test_hostile_messages_are_dropped_and_counted_and_the_result_is_unchanged(tmp_path, undisturbed, capsys):
    # Given a 2-peer run, an outsider connected to both peers that has seen a whole step of their
    # traffic, and an operator who then asks to pause
    out = tmp_path / "attacked"
    procs, logs, endpoints = start_run("attacked", out)
    attacker = Attacker("attacked", endpoints)
    acks = {}
    seen_step = attacker.wait_for_a_whole_step()

    # (a resume sent while the run goes on is rejected: test_steering, every way of running; here it
    # raced the pause on a loaded machine, overtook it and resumed the held run)
    try:
        acks["pause"] = _control(capsys, endpoints[0], "attacked", "pause", timeout="120")
        rc, err = acks["pause"]
        assert rc == 0 and "sph control: accepted at step" in err, err
        step = int(err.rsplit("accepted at step", 1)[1].split()[0])
        assert step > seen_step and step < STEPS, (step, seen_step)
        # When, while the run is held after that step, the outsider sends every kind of hostile message
        # (those for the next steps sit in peer 0's mailbox ahead of the genuine ones), and the operator
        # tries a bad value and a second pause, then resumes
        for rank, log in enumerate(logs):
            log.wait_for(f"peer {rank}: step {step}: pause", timeout=60)
        time.sleep(0.2)
        seen = len(attacker.steps_seen)
        attacker.once(step - 1)
        attacker.semantic(step)                  # for step `step`, the first after the pause
        attacker.replay(dest=0, step=step - 1)  # peer 0 already used it: a duplicate
        attacker.replay(dest=1, step=step - 1)  # peer 1 waits for step `step`'s resume: an old step
        # peer 0's reductions seen meanwhile that are past the held step: none. (Not how many arrived:
        # a cold suite on 2 cores counted 547 in this window, 2026-12-07, while the run ended with the
        # undisturbed bits; on a loaded machine this session's subscriber can file earlier steps late.)
        acks["held"] = [s for s in attacker.steps_seen[seen:] if s > step]
        # The replays were sent last, on the same link, and are dropped on arrival: once each peer has
        # logged its drop, every forged message before it is filed (else the resume could overtake them
        # while peer 0 is still working through the 5000-message flood)
        logs[0].wait_for("peer 0: dropped a message from 1 (duplicate)", timeout=60)
        logs[1].wait_for("peer 1: dropped a message from 0 (old step)", timeout=60)
        acks["bad value"] = _control(capsys, endpoints[0], "attacked", "set", "sph.alpha=-1")
        acks["pause again"] = _control(capsys, endpoints[0], "attacked", "pause")
        acks["resume"] = _control(capsys, endpoints[0], "attacked", "resume")
        results = finish(procs, logs)
    finally:
        attacker.close()
        for p in procs:
            p.kill()
    # Then both peers exit 0 and the result is the undisturbed run's, bit for bit
    assert [rc for rc, _ in results] == [0, 0], results
    calm, hit = np.load(undisturbed / "final.npz"), np.load(out / "final.npz")
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(calm[key], hit[key]), key
    # And every command was answered: the pause accepted at the step after
    # which both peers held, the bad value and the second pause rejected with the reason, the resume accepted
    assert acks["held"] == [], acks["held"]
    rc, err = acks["bad value"]
    assert rc == 2 and "sph control: rejected:" in err and "sph.alpha" in err, err
    rc, err = acks["pause again"]
    assert rc == 2 and f"rejected: pause: the run is already paused after step {step}" in err, err
    rc, err = acks["resume"]
    assert rc == 0 and f"sph control: accepted at step {step}" in err, err
    s = json.loads((out / "summary.json").read_text())
    assert all(p["controls"] == [[step, "pause"]] for p in s["per_peer"]), [p["controls"] for p in s["per_peer"]]
    assert s["steps"] == STEPS
    # And every hostile message was dropped and counted, by source and reason; the undisturbed run dropped none
    calm_summary = json.loads((undisturbed / "summary.json").read_text())
    assert calm_summary["dropped_messages"] == 0 and all(not p["dropped"] for p in calm_summary["per_peer"])
    assert drops_of(s, 0) == {
        "1": {"malformed": 1, "oversized": 1, "future step": 5001, "unused": 1, "duplicate": 1,
              "dtype": 1, "not finite": 1, "count": 1, "control": 1, "owner": 1},
        "other": {"wrong key": 2},
        "controller": {"wrong source": 1, "malformed": 1}}
    assert drops_of(s, 1) == {"0": {"old step": 1}}, results[1][1]
    assert [p["dropped_messages"] for p in s["per_peer"]] == [attacker.sent[0], attacker.sent[1]]
    assert s["dropped_messages"] == sum(attacker.sent.values()) == sum(s["dropped_by_reason"].values())


def test_sph_control_says_so_when_no_run_answers(capsys):
    port = free_ports(1)[0]
    rc, err = _control(capsys, f"tcp/127.0.0.1:{port}", "nobody", "pause", timeout="1")
    assert rc == 4 and "no run 'nobody' is listening" in err and "nothing was sent" in err, err


# -- the receiver's checks on in-process peers -------------------------------------------------------
def _forge_ahead(cluster, step):
    """Forged messages for ``step``, put in the mailboxes ahead of the genuine ones; returns the
    reasons each is expected to be dropped for, by receiving rank."""
    net = cluster.network
    one, zero = cluster.peers[1].state, cluster.peers[0].state
    # peer 1's particles farthest from the cut: in its block, so none is peer 0's migrant; peer 0's
    # farthest: not in peer 1's incoming zone
    far_one = np.argsort(-one.x[:one.n_owned, 0], kind="stable")[:4]
    far_zero = np.argsort(zero.x[:zero.n_owned, 0], kind="stable")[:2]
    ghost = {k: a[far_one] for k, a in one.carried_arrays(one.n_owned).items()}
    intruder = {k: a[far_zero] for k, a in zero.carried_arrays(zero.n_owned).items()}
    n_ghosts = {r: h._ghost_rows.get(1 - r, (0, 0)) for r, h in enumerate(cluster.halos)}
    expected = {0: [], 1: []}

    def put(dest, phase, arrays, reason):
        net.deliver(dest, 1 - dest, (step, phase), arrays)
        expected[dest].append(reason)

    put(0, "migrants", dict(ghost, x=ghost["x"].astype(np.float32)), "dtype")
    put(0, "migrants", ghost, "owner")
    put(0, "positions", dict(ghost, x=np.full_like(ghost["x"], np.nan)), "not finite")
    put(0, "positions", dict(ghost, m=-ghost["m"]), "mass")
    put(0, "positions", dict(ghost, id=np.full(4, 10 ** 9)), "ids")
    put(0, "positions", dict(ghost, id=ghost["id"][[0, 1, 2, 1]]), "ids")  # valid ids, one of them twice
    put(0, "positions", dict(ghost, extra=np.zeros(4)), "arrays")
    put(1, "positions", intruder, "owner")
    lo, hi = n_ghosts[0]
    put(0, "fields", {"rho": np.zeros(hi - lo + 1000), "p": np.zeros(hi - lo + 1000)}, "count")
    put(1, "fields", {"rho": np.zeros((5, 2)), "p": np.zeros(5)}, "shape")
    put(0, "reduce", {"stats": np.zeros(4), "control": np.frombuffer(b"[]", np.uint8)}, "control")
    put(0, "reduce", {"stats": np.array([0.0, 0.0, -1.0, 0.0])}, "stats")
    put(1, "reduce", {"stats": np.zeros(4), "control": np.frombuffer(b"[[[[", np.uint8)}, "control")
    put(1, "reduce", {"stats": np.zeros(3)}, "count")
    return expected


@pytest.mark.fast
def test_in_process_peers_drop_what_breaks_the_protocol_and_stay_bitwise_equal():
    from nodes.cluster import InProcessCluster
    # Given two in-process clusters of the same scene, one of them fed forged messages ahead of
    # the genuine ones in steps 3 to 6
    sc = scene("dam_break_2d", "particles.spacing=0.01", "run.neighbour_skin=0")  # exchange 1 every step
    calm = InProcessCluster(sc, 2, "f64", dims=(2, 1, 1))
    hit = InProcessCluster(sc, 2, "f64", dims=(2, 1, 1))
    expected = {0: {}, 1: {}}
    for step in range(10):
        calm.step()
        if 3 <= step <= 6:
            for rank, reasons in _forge_ahead(hit, step).items():
                for reason in reasons:
                    expected[rank][reason] = expected[rank].get(reason, 0) + 1
        hit.step()
    # Then every forged message was rejected for what it is, and the result did not change
    for rank, halo in enumerate(hit.halos):
        assert halo.transport.drops == {str(1 - rank): expected[rank]}, (rank, halo.transport.drops)
    assert all(h.transport.dropped == 0 for h in calm.halos)
    a, b = calm.final_arrays(), hit.final_arrays()
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(a[key], b[key]), key


@pytest.mark.fast
def test_a_repeated_id_is_found_wherever_it_sits():
    from sphcore.halo import has_repeats
    ids = np.random.default_rng(5).permutation(10_000)[:3072].astype(np.int64)
    assert not has_repeats(ids) and not has_repeats(ids[:1]) and not has_repeats(ids[:0])
    for a, b in [(0, 1), (0, 3071), (1500, 17), (3071, 3070)]:
        twice = ids.copy()
        twice[b] = twice[a]
        assert has_repeats(twice), (a, b)
    assert has_repeats(np.array([-1, 5, -1]))

