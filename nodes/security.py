"""Trust for a run: a run CA, one certificate per process, mutually authenticated TLS and an
access-control list on every Zenoh session.

Threat model (docs/USAGE.md "Security" says the same for users): anyone who can reach a peer's
port is an outsider until proven otherwise, another user of the same machine included. So every
run has its own certificate authority, made by the launcher (or ``sph certs``) in a folder only its
user can read, and every process of the run holds one certificate signed by it:

    peer-R      peer of rank R        (its host name or address in the certificate: others verify it)
    viewer      the viewer            (composites framelets; may only subscribe to them)
    control     the controller        (``sph control``; may only send commands and read their acks)

The CA's private key is thrown away once the certificates are issued: nobody, not even the
launcher, can add a member to a run later. Zenoh then runs on ``tls/`` endpoints with mTLS (both
ends show a certificate of the run CA) and name verification (the address dialled must be in the
listener's certificate), and each session declares an access-control list that admits, from each
certificate, only the messages of its role in this run (``access_control``): peer q may publish
only on keys that name q as the source, so the source of every halo message is authenticated by
the transport. What a holder of a valid certificate can still do is listed in docs/USAGE.md.

Without TLS (``--insecure``) there is no authentication at all; ``check_endpoints`` refuses to
listen on anything but loopback then.
"""
from __future__ import annotations

import base64
import datetime
import ipaddress
import json
import os
import re
import stat
from dataclasses import dataclass
from pathlib import Path

from nodes import wire

VIEWER = "viewer"
CONTROL = "control"
CA_FILE = "ca.pem"
DEFAULT_DAYS = 30
LOOPBACK_NAMES = ("127.0.0.1", "localhost", "::1")


class SecurityError(ValueError):
    """Credentials that are missing, unreadable, too widely readable or do not fit the run."""


def peer_name(rank: int) -> str:
    return f"peer-{rank}"


@dataclass(frozen=True)
class Identity:
    """One process's credentials: its certificate's common name, the run CA and its own
    certificate and private key (PEM)."""
    name: str
    ca_pem: bytes
    cert_pem: bytes
    key_pem: bytes

    def to_json(self) -> str:
        """One line, for handing credentials to a remote process over its stdin (never argv:
        other users can read a command line)."""
        return json.dumps({"name": self.name, **{k: base64.b64encode(getattr(self, k)).decode()
                                                 for k in ("ca_pem", "cert_pem", "key_pem")}})

    @staticmethod
    def from_json(line: str) -> "Identity":
        try:
            d = json.loads(line)
            return Identity(str(d["name"]), *(base64.b64decode(d[k], validate=True)
                                              for k in ("ca_pem", "cert_pem", "key_pem")))
        except (ValueError, KeyError, TypeError) as e:
            raise SecurityError(f"credentials on stdin are not readable ({e})") from None


# -- making a run's credentials ---------------------------------------------------------------------
def _subject_alt_names(hosts):
    from cryptography import x509
    names = []
    for h in dict.fromkeys(hosts):  # unique, in order
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            names.append(x509.DNSName(h))
    return names


def make_run_credentials(folder: Path, peer_hosts: list[list[str]], viewer_hosts=LOOPBACK_NAMES,
                         days: int = DEFAULT_DAYS) -> dict[str, Identity]:
    """Make a fresh run CA in ``folder`` (created with mode 0700; files 0600) and issue one
    certificate per peer (``peer_hosts[r]``: the names and addresses others dial to reach peer r),
    one for the viewer and one for the controller. The CA key is never written: it is gone when
    this returns. Returns the identities by name."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    folder = Path(folder)
    if not 1 <= days <= 3650:
        raise SecurityError(f"--days {days}: a certificate is valid for 1 to 3650 days")
    for hosts in list(peer_hosts) + [list(viewer_hosts)]:
        for h in hosts:
            check_host(h)
    if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
        raise SecurityError(f"{folder}: exists and is not an empty folder; credentials are made in a new "
                            "folder (remove it first)")
    try:
        folder.mkdir(parents=True, exist_ok=True, mode=0o700)
        os.chmod(folder, 0o700)
    except OSError as e:
        raise SecurityError(f"{folder}: cannot make the credentials folder: {e.strerror}") from None
    now = datetime.datetime.now(datetime.timezone.utc)
    begin, end = now - datetime.timedelta(minutes=10), now + datetime.timedelta(days=days)

    def name(cn):
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = name(f"sph run CA {os.urandom(6).hex()}")
    ca = (x509.CertificateBuilder().subject_name(ca_name).issuer_name(ca_name).public_key(ca_key.public_key())
          .serial_number(x509.random_serial_number()).not_valid_before(begin).not_valid_after(end)
          .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
          .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                       content_commitment=False, key_encipherment=False, data_encipherment=False,
                                       key_agreement=False, encipher_only=False, decipher_only=False), critical=True)
          .sign(ca_key, hashes.SHA256()))
    ca_pem = ca.public_bytes(serialization.Encoding.PEM)

    def issue(cn, hosts) -> Identity:
        key = ec.generate_private_key(ec.SECP256R1())
        cert = (x509.CertificateBuilder().subject_name(name(cn)).issuer_name(ca_name).public_key(key.public_key())
                .serial_number(x509.random_serial_number()).not_valid_before(begin).not_valid_after(end)
                .add_extension(x509.SubjectAlternativeName(_subject_alt_names(hosts)), critical=False)
                .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
                .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                      ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
                .sign(ca_key, hashes.SHA256()))
        return Identity(cn, ca_pem, cert.public_bytes(serialization.Encoding.PEM),
                        key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                          serialization.NoEncryption()))

    ids = {peer_name(r): issue(peer_name(r), list(h) + ["127.0.0.1", "localhost"]) for r, h in enumerate(peer_hosts)}
    ids[VIEWER] = issue(VIEWER, list(viewer_hosts) + ["127.0.0.1", "localhost"])
    ids[CONTROL] = issue(CONTROL, ["127.0.0.1", "localhost"])
    _write_private(folder / CA_FILE, ca_pem)
    for ident in ids.values():
        _write_private(folder / f"{ident.name}.pem", ident.cert_pem)
        _write_private(folder / f"{ident.name}.key", ident.key_pem)
    return ids


_HOSTNAME = re.compile(r"^(?=.{1,253}$)[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?"
                       r"(\.[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*$")


def check_host(host: str) -> str:
    """A host as a certificate can name it: an IPv4/IPv6 address or a DNS name."""
    try:
        ipaddress.ip_address(host)
        return host
    except ValueError:
        pass
    if not _HOSTNAME.match(host):
        raise SecurityError(f"host {host!r}: not an IP address or a DNS name (letters, digits, '-' and '.')")
    return host


def _write_private(path: Path, data: bytes):
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def load_identity(folder: Path, name: str) -> Identity:
    """``name``'s credentials from a folder made by ``make_run_credentials`` (``sph certs``). Refuses
    a private key that other users can read, as ssh does."""
    folder = Path(folder)
    paths = [folder / CA_FILE, folder / f"{name}.pem", folder / f"{name}.key"]
    for p in paths:
        if not p.is_file():
            raise SecurityError(f"--tls {folder}: {p.name} is missing (make the run's credentials with "
                                f"`sph certs {folder} ...`; this process is {name!r})")
    mode = paths[2].stat().st_mode
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise SecurityError(f"--tls {folder}: {paths[2].name} is readable by other users (mode "
                            f"{stat.S_IMODE(mode):o}); chmod 600 it")
    try:
        return Identity(name, *(p.read_bytes() for p in paths))
    except OSError as e:
        raise SecurityError(f"--tls {folder}: cannot read {e.filename}: {e.strerror}") from None


# -- Zenoh configuration ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Trust:
    """What a Zenoh session of a secure run needs: who it is, which run, how many peers."""
    identity: Identity
    run: str
    world: int


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode()


def apply(conf, trust: Trust):
    """Add mTLS with name verification and this process's access-control list to a Zenoh config."""
    ident = trust.identity
    tls = {"root_ca_certificate_base64": _b64(ident.ca_pem),
           "listen_private_key_base64": _b64(ident.key_pem), "listen_certificate_base64": _b64(ident.cert_pem),
           "connect_private_key_base64": _b64(ident.key_pem), "connect_certificate_base64": _b64(ident.cert_pem),
           "enable_mtls": True, "verify_name_on_connect": True}
    conf.insert_json5("transport/link/tls", json.dumps(tls))
    conf.insert_json5("access_control", json.dumps(access_control(trust.run, ident.name, trust.world)))


_LIVELINESS = ["liveliness_token", "declare_liveliness_subscriber", "liveliness_query", "reply"]


def access_control(run: str, me: str, world: int) -> dict:
    """The access-control list of process ``me`` of run ``run``: default deny; from each of the
    run's certificates only the messages of its role (ingress); anything to the run's members
    (egress: they filter what they accept themselves)."""
    k = f"sph/{run}"
    rules, subjects, policies = [], [], []

    def allow(subject_id, cn, entries):
        """entries: (messages, key expressions) admitted from certificate ``cn``."""
        subjects.append({"id": subject_id, "cert_common_names": [cn]})
        ids = []
        for i, (messages, keys) in enumerate(entries):
            rules.append({"id": f"{subject_id}-{i}", "permission": "allow", "flows": ["ingress"],
                          "messages": messages, "key_exprs": keys})
            ids.append(f"{subject_id}-{i}")
        policies.append({"rules": ids, "subjects": [subject_id]})

    for q in range(world):
        name = peer_name(q)
        if name == me:
            continue
        allow(name, name, [
            (["put"], [wire.halo_key(run, r, q) for r in range(world) if r != q]  # halo messages from q
             + [wire.frame_key(run, q)] * (me == VIEWER) + [wire.ack_key(run)] * (me == CONTROL and q == 0)),
            # q's own inbox, nobody else's; rank 0 also takes the commands
            (["declare_subscriber"], [wire.inbox_key(run, q)] + [wire.control_key(run)] * (q == 0)),
            (_LIVELINESS, [wire.alive_key(run, q), wire.alive_all(run)]),
        ])
    if me != VIEWER:
        allow(VIEWER, VIEWER, [(["declare_subscriber"], [wire.frame_all(run)])])
    if me != CONTROL:
        allow(CONTROL, CONTROL, [(["put"], [wire.control_key(run)]), (["declare_subscriber"], [wire.ack_key(run)])])
    rules.append({"id": "to-members", "permission": "allow", "flows": ["egress"],
                  "messages": ["put", "declare_subscriber"] + _LIVELINESS, "key_exprs": [f"{k}/**"]})
    subjects.append({"id": "members", "cert_common_names": sorted(
        {peer_name(q) for q in range(world)} | {VIEWER, CONTROL})})
    policies.append({"rules": ["to-members"], "subjects": ["members"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def _host_of(endpoint: str) -> str:
    address = endpoint.split("/", 1)[1].split("#", 1)[0]
    host = address.rsplit(":", 1)[0]
    return host.strip("[]")


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_endpoints(listen: list[str], connect: list[str], secure: bool) -> None:
    """Endpoints fit the security mode: ``tls/`` with credentials; with ``--insecure`` ``tcp/``
    and listening on loopback only (plain TCP off the machine would let anyone join or read)."""
    for ep in list(listen) + list(connect):
        proto = ep.split("/", 1)[0] if "/" in ep else ""
        if secure and proto != "tls":
            raise SecurityError(f"endpoint {ep!r}: a secure run uses tls/HOST:PORT endpoints "
                                "(plain tcp/ only with --insecure)")
        if not secure and proto not in ("tcp", "tls"):
            raise SecurityError(f"endpoint {ep!r}: expected tcp/HOST:PORT (or tls/ with --tls DIR)")
    if not secure:
        for ep in listen:
            host = _host_of(ep)
            if not is_loopback(host):
                raise SecurityError(f"--listen {ep}: without TLS a peer listens on loopback only (anyone who "
                                    "reaches the port could join the run or read it); use --tls DIR")
