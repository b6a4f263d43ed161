"""The wire: Zenoh key expressions and the message format, in one place.

Key expressions (every one under ``sph/<run>/``, so two runs on one network never mix):

    sph/<run>/halo/<dest>/<source>     halo messages from peer <source> to peer <dest>
    sph/<run>/alive/<rank>             liveliness token of peer <rank> (gone = the peer died)
    sph/<run>/frame/<rank>             framelets (and rank 0's "end") from peer <rank> to any viewer
    sph/<run>/control                  commands from a controller (source -2) to rank 0 (nodes/control.py)

A message is a small self-describing header and the raw bytes of numpy arrays; nothing is ever
unpickled from the network:

    offset 0   4 bytes   magic b"SPHW"
           4   uint16    format version (little endian)
           6   uint32    header length L
          10   L bytes   header, UTF-8 JSON: {"run", "step", "phase", "source", "dest",
                                              "arrays": [[name, dtype, shape], ...]}
        10+L   ...       the arrays' bytes, C order, in the header's order, nothing else

``decode`` checks everything before any array is built (magic, version, run, destination,
source rank, phase, dtypes from a fixed list, shapes, total size) and raises ``WireError``, which
the receiver logs and drops: a malformed or foreign message never crashes a peer.
"""
from __future__ import annotations

import json
import math
import re
import struct

import numpy as np

MAGIC = b"SPHW"
VERSION = 1
_PREFIX = struct.Struct("<4sHI")
MAX_HEADER = 64 * 1024
DTYPES = frozenset({"<f4", "<f8", "<i4", "<i8", "<u1", "<i1", "<u8"})
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,31}$")
_RUN = re.compile(r"^[A-Za-z0-9_-]{1,64}$")


class WireError(ValueError):
    """A message that is malformed, from another run, or not for this peer."""


def check_run_id(run: str) -> str:
    if not isinstance(run, str) or not _RUN.match(run):
        raise ValueError(f"run id {run!r}: use 1-64 letters, digits, '-' or '_'")
    return run


def halo_key(run: str, dest: int, source: int) -> str:
    return f"sph/{run}/halo/{dest}/{source}"


def inbox_key(run: str, rank: int) -> str:
    """Everything addressed to ``rank``."""
    return f"sph/{run}/halo/{rank}/*"


def alive_key(run: str, rank: int) -> str:
    return f"sph/{run}/alive/{rank}"


def alive_all(run: str) -> str:
    return f"sph/{run}/alive/*"


def frame_key(run: str, rank: int) -> str:
    return f"sph/{run}/frame/{rank}"


def frame_all(run: str) -> str:
    return f"sph/{run}/frame/*"


CONTROLLER = -2  # the source rank of control commands


def control_key(run: str) -> str:
    return f"sph/{run}/control"


def rank_from_key(key: str) -> int:
    """The last segment of a key expression as a rank (``alive`` and ``halo`` keys)."""
    return int(str(key).rsplit("/", 1)[-1])


def encode(run: str, step: int, phase: str, source: int, dest: int, arrays: dict) -> bytes:
    """One message: header + raw array bytes (arrays are made little-endian and C-contiguous)."""
    table, chunks = [], []
    for name, a in arrays.items():
        a = np.ascontiguousarray(a)
        if a.dtype.byteorder == ">" or (a.dtype.byteorder == "=" and not np.little_endian):
            a = a.astype(a.dtype.newbyteorder("<"))
        dtype = a.dtype.str
        if dtype == "|u1":
            dtype = "<u1"
        elif dtype == "|i1":
            dtype = "<i1"
        if dtype not in DTYPES or not _NAME.match(name):
            raise ValueError(f"cannot send array {name!r} of dtype {a.dtype}")
        table.append([name, dtype, list(a.shape)])
        chunks.append(a.tobytes())
    header = json.dumps({"run": run, "step": int(step), "phase": phase, "source": int(source), "dest": int(dest),
                         "arrays": table}, separators=(",", ":")).encode()
    return b"".join([_PREFIX.pack(MAGIC, VERSION, len(header)), header] + chunks)


def decode(data: bytes, run: str, dest: int, world: int, sources=None) -> tuple[int, tuple, dict]:
    """(source, (step, phase), arrays) of a message for peer ``dest`` of run ``run`` with ``world``
    peers (or from one of ``sources``); raises WireError if anything does not fit."""
    view = memoryview(data)
    if len(view) < _PREFIX.size:
        raise WireError(f"message of {len(view)} bytes is shorter than the {_PREFIX.size}-byte prefix")
    magic, version, hlen = _PREFIX.unpack_from(view, 0)
    if magic != MAGIC:
        raise WireError(f"not an sph message (magic {bytes(magic)!r})")
    if version != VERSION:
        raise WireError(f"wire format version {version}, this peer speaks {VERSION}")
    if hlen > MAX_HEADER or _PREFIX.size + hlen > len(view):
        raise WireError(f"header length {hlen} does not fit a {len(view)}-byte message")
    try:
        head = json.loads(bytes(view[_PREFIX.size:_PREFIX.size + hlen]).decode())
        msg_run, step, phase = head["run"], head["step"], head["phase"]
        source, msg_dest, table = head["source"], head["dest"], head["arrays"]
    except (ValueError, KeyError, TypeError, UnicodeDecodeError) as e:
        raise WireError(f"unreadable header: {e}") from None
    if msg_run != run:
        raise WireError(f"message of run {msg_run!r}, this is run {run!r}")
    if msg_dest != dest:
        raise WireError(f"message for peer {msg_dest!r} delivered to peer {dest}")
    if sources is not None:
        if source not in sources:
            raise WireError(f"source {source!r} is not one of {sorted(sources)}")
    elif not (isinstance(source, int) and 0 <= source < world and source != dest):
        raise WireError(f"source rank {source!r} is not another peer of this {world}-peer run")
    if not (isinstance(step, int) and step >= -1) or not (isinstance(phase, str) and _NAME.match(phase)):
        raise WireError(f"bad step {step!r} or phase {phase!r}")
    if not isinstance(table, list):
        raise WireError("array table is not a list")
    arrays, offset = {}, _PREFIX.size + hlen
    for entry in table:
        try:
            name, dtype, shape = entry
        except (TypeError, ValueError):
            raise WireError(f"bad array entry {entry!r}") from None
        if not (isinstance(name, str) and _NAME.match(name)) or name in arrays or dtype not in DTYPES:
            raise WireError(f"bad array name {name!r} or dtype {dtype!r}")
        if not (isinstance(shape, list) and len(shape) <= 4
                and all(isinstance(d, int) and not isinstance(d, bool) and d >= 0 for d in shape)):
            raise WireError(f"array {name!r}: bad shape {shape!r}")
        nbytes = math.prod(shape) * np.dtype(dtype).itemsize
        if offset + nbytes > len(view):
            raise WireError(f"array {name!r} ({nbytes} bytes) runs past the end of the message")
        arrays[name] = np.frombuffer(view, dtype=dtype, count=math.prod(shape), offset=offset).reshape(shape)
        offset += nbytes
    if offset != len(view):
        raise WireError(f"{len(view) - offset} bytes left over after the arrays")
    return source, (step, phase), arrays
