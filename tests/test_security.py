"""Trust: the run's credentials, mutually authenticated TLS and the access-control list, over real
Zenoh sessions on loopback. An outsider (no certificate of the run's CA, or plain TCP) cannot
connect; a member can publish only what its role allows."""
import os
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from launch.cli import main
from launch.local import free_ports
from nodes import security, wire
from nodes.zenoh_transport import PeerTimeout, ZenohEndpoint, zenoh_config

ROOT = Path(__file__).resolve().parent.parent
TINY = ["configs/tiny.toml", "--steps", "20", "--precision", "f64", "--set", "render.every=0"]


@pytest.fixture(scope="module")
def creds(tmp_path_factory):
    folder = tmp_path_factory.mktemp("run") / "tls"
    return folder, security.make_run_credentials(folder, [["127.0.0.1"]] * 3)


def test_credentials_are_private_and_the_ca_key_is_gone(creds):
    folder, ids = creds
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    names = sorted(p.name for p in folder.iterdir())
    assert names == sorted(["ca.pem"] + [f"{n}.{e}" for n in ("peer-0", "peer-1", "peer-2", "viewer", "control")
                                          for e in ("pem", "key")])
    assert all(stat.S_IMODE(p.stat().st_mode) == 0o600 for p in folder.iterdir())
    assert b"PRIVATE KEY" not in (folder / "ca.pem").read_bytes()
    assert security.load_identity(folder, "peer-1") == ids["peer-1"]
    assert security.Identity.from_json(ids["viewer"].to_json()) == ids["viewer"]


def test_credentials_refuse_a_key_others_can_read_and_a_used_folder(tmp_path, creds):
    folder, _ = creds
    with pytest.raises(security.SecurityError, match="not an empty folder"):
        security.make_run_credentials(folder, [["127.0.0.1"]])
    loose = tmp_path / "loose"
    security.make_run_credentials(loose, [["127.0.0.1"]])
    os.chmod(loose / "peer-0.key", 0o644)
    with pytest.raises(security.SecurityError, match="readable by other users"):
        security.load_identity(loose, "peer-0")
    with pytest.raises(security.SecurityError, match="peer-5.pem is missing"):
        security.load_identity(loose, "peer-5")
    with pytest.raises(security.SecurityError, match="not readable"):
        security.Identity.from_json('{"name": "peer-0"}')


def _trust(ids, name, world=3, run="sec"):
    return security.Trust(ids[name], run, world)


def _put_from(trust, endpoint, key, payload):
    """Publish one message from a fresh session with ``trust`` (None: plain TCP), then close it."""
    import zenoh
    try:
        session = zenoh.open(zenoh_config([], [endpoint], trust=trust))
    except Exception:  # zenoh refuses to open (e.g. the handshake failed at start)
        return
    time.sleep(1.0)  # let the session connect (or be refused)
    session.put(key, payload)
    time.sleep(0.5)
    session.close()


def test_only_members_connect_and_each_publishes_only_its_own_keys(creds, tmp_path):
    folder, ids = creds
    ports = free_ports(3)
    tls = [f"tls/127.0.0.1:{p}" for p in ports]
    # Given peers 0 and 1 of a 3-peer run on TLS (peer 2 is not started)
    a = ZenohEndpoint("sec", 0, 3, [tls[0]], [], timeout=5, trust=_trust(ids, "peer-0"))
    b = ZenohEndpoint("sec", 1, 3, [tls[1]], [tls[0]], timeout=5, trust=_trust(ids, "peer-1"))
    try:
        deadline = time.time() + 10
        while not {0, 1} <= a._alive and time.time() < deadline:
            time.sleep(0.05)
        # Then a genuine message from peer 1 arrives
        b.send(0, (0, "positions"), {"x": np.ones(3)})
        assert np.array_equal(a.wait(1, (0, "positions"))["x"], np.ones(3))

        def forged(phase, source):  # step 0, inside any step window: only the access control can stop it
            return wire.encode("sec", 0, phase, source, 0, {"x": np.zeros(3)})

        other_ca = security.make_run_credentials(tmp_path / "other", [["127.0.0.1"]] * 3)
        # When outsiders and members try to publish what they may not
        _put_from(None, f"tcp/127.0.0.1:{ports[0]}", wire.halo_key("sec", 0, 1), forged("p1", 1))   # plain TCP
        _put_from(_trust(other_ca, "peer-1"), tls[0], wire.halo_key("sec", 0, 1), forged("p2", 1))  # another CA
        _put_from(_trust(ids, "control"), tls[0], wire.halo_key("sec", 0, 1), forged("p3", 1))     # wrong role
        _put_from(_trust(ids, "viewer"), tls[0], wire.control_key("sec"), b"pause")               # wrong role
        _put_from(_trust(ids, "peer-2"), tls[0], wire.halo_key("sec", 0, 1), forged("p4", 1))      # as peer 1
        # and peer 2 sends as itself
        _put_from(_trust(ids, "peer-2"), tls[0], wire.halo_key("sec", 0, 2), forged("p5", 2))
        # Then only peer 2's own message got through
        assert np.array_equal(a.wait(2, (0, "p5"))["x"], np.zeros(3))
        # and a member with a valid certificate sends hostile messages on its own key: each is dropped, counted
        nested = b"[" * 30000 + b"]" * 30000
        _put_from(_trust(ids, "peer-2"), tls[0], wire.halo_key("sec", 0, 2),
                  b"SPHW\x01\x00" + len(nested).to_bytes(4, "little") + nested)
        _put_from(_trust(ids, "peer-2"), tls[0], wire.halo_key("sec", 0, 2), forged("p5", 1))  # says it is 1
        deadline = time.time() + 5
        while a.dropped < 2 and time.time() < deadline:
            time.sleep(0.05)
        assert a.drops == {"2": {"malformed": 1, "wrong key": 1}}, a.drops
        a.timeout = 0.3
        for phase in ("p1", "p2", "p3", "p4"):
            with pytest.raises(PeerTimeout):
                a.wait(1, (0, phase))
        assert a.take_commands() == []
    finally:
        b.close()
        a.close()


def test_endpoints_must_fit_the_security_mode():
    with pytest.raises(security.SecurityError, match="loopback only"):
        security.check_endpoints(["tcp/0.0.0.0:7447"], [], secure=False)
    with pytest.raises(security.SecurityError, match="loopback only"):
        security.check_endpoints(["tcp/198.18.0.2:7447"], [], secure=False)
    with pytest.raises(security.SecurityError, match="tls/HOST:PORT"):
        security.check_endpoints(["tcp/127.0.0.1:7447"], [], secure=True)
    security.check_endpoints(["tcp/127.0.0.1:7447"], ["tcp/[::1]:7448"], secure=False)
    security.check_endpoints(["tls/0.0.0.0:7447"], ["tls/node2:7447"], secure=True)


def test_peer_refuses_plain_tcp_off_loopback_and_asks_how_to_authenticate(capsys, tmp_path):
    base = ["peer", "configs/tiny.toml", "--rank", "0", "--world", "2", "--run-id", "x"]
    assert main(base + ["--listen", "tcp/0.0.0.0:7447", "--insecure"]) == 2
    assert "loopback only" in capsys.readouterr().err
    assert main(base + ["--listen", "tls/127.0.0.1:7447"]) == 2
    assert "--tls DIR" in capsys.readouterr().err
    assert main(base + ["--listen", "tls/127.0.0.1:7447", "--tls", str(tmp_path)]) == 2
    assert "ca.pem is missing" in capsys.readouterr().err


def test_a_tls_run_and_an_insecure_run_give_the_same_bits(tmp_path):
    # Given the tiny scene on 2 peers, once with TLS (the default) and once with --insecure
    for name, extra in (("tls", []), ("plain", ["--insecure"])):
        done = subprocess.run([sys.executable, "-m", "launch.cli", "run", *TINY, "--peers", "2", "--out",
                               str(tmp_path / name), "--quiet", *extra], cwd=ROOT, capture_output=True, text=True,
                              timeout=300)
        assert done.returncode == 0, done.stderr
    # Then both give the same result; the insecure one said what it gives away
    assert "--insecure: plain TCP" in done.stderr
    one, two = np.load(tmp_path / "tls" / "final.npz"), np.load(tmp_path / "plain" / "final.npz")
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(one[key], two[key]), key
    assert (tmp_path / "tls" / "tls" / "ca.pem").exists() and not (tmp_path / "plain" / "tls").exists()


@pytest.mark.parametrize("argv, fragment", [
    (["--peer-host", "bad host!"], "not an IP address or a DNS name"),
    (["--peers", "1", "--days", "0"], "valid for 1 to 3650 days"),
    (["--peers", "0"], "at least one peer"),
])
def test_sph_certs_refuses_bad_input_and_writes_nothing(tmp_path, capsys, argv, fragment):
    assert main(["certs", str(tmp_path / "c"), *argv]) == 2
    assert fragment in capsys.readouterr().err
    assert not (tmp_path / "c").exists()


def test_sph_certs_refuses_a_file_or_a_used_folder(tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    assert main(["certs", str(tmp_path / "file"), "--peers", "1"]) == 2
    assert "not an empty folder" in capsys.readouterr().err
    assert main(["certs", str(tmp_path / "c"), "--peers", "2"]) == 0
    assert main(["certs", str(tmp_path / "c"), "--peers", "2"]) == 2
    assert "not an empty folder" in capsys.readouterr().err
