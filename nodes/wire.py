"""The wire: Zenoh key expressions and the message format, in one place.

Key expressions (every one under ``sph/<run>/``, so two runs on one network never mix):

    sph/<run>/halo/<dest>/<source>     halo messages from peer <source> to peer <dest>
    sph/<run>/alive/<rank>             liveliness token of peer <rank> (gone = the peer died)
    sph/<run>/frame/<rank>             framelets (and rank 0's "end") from peer <rank> to any viewer (dest -1)
    sph/<run>/control                  commands from a controller (source -2) to rank 0 (nodes/control.py)
    sph/<run>/ack                      rank 0's answer to each command: accepted at step N, or rejected

A message is a small self-describing header and the raw bytes of numpy arrays; nothing is ever
unpickled from the network:

    offset 0   4 bytes   magic b"SPHW"
           4   uint16    format version (little endian)
           6   uint32    header length L
          10   L bytes   header, UTF-8 JSON: {"run", "step", "phase", "source", "dest",
                                              "arrays": [[name, dtype, shape], ...]}
        10+L   ...       the arrays' bytes, C order, in the header's order, nothing else

``decode`` checks everything before any array is built and raises ``WireError`` (never anything
else, whatever the bytes), which the receiver counts and drops: a malformed or foreign message never
crashes a peer. In order: the total size (``max_bytes``, before anything is parsed), magic, version,
header length, a flat header (at most ``_MAX_DEPTH`` levels of brackets, checked on the raw text
before the JSON parser sees it, so a deeply nested header cannot exhaust the parser's recursion),
exactly the six header fields with their types (integers are never booleans), run, destination,
source rank, step, phase, an array table of at most ``MAX_ARRAYS`` entries with dtypes from a fixed
list and shapes of at most 4 dimensions, and the arrays' bytes adding up to the message's length.
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
MAX_MESSAGE = 256 * 1024 * 1024  # bytes; receivers may set a smaller, scene-sized limit (nodes/peer.py)
MAX_ARRAYS = 64
MAX_STEP = 2 ** 53               # larger step numbers are not a run's (and not exact in a float)
DTYPES = frozenset({"<f4", "<f8", "<i4", "<i8", "<u1", "<i1", "<u8"})
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,31}$")
_RUN = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
_FIELDS = frozenset({"run", "step", "phase", "source", "dest", "arrays"})
_MAX_DEPTH = 4                   # {  "arrays": [  [name, dtype,  [shape]  ]  ]  }
_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.S)
_BRACKET = re.compile(r"[\[\]{}]")


class WireError(ValueError):
    """A message that is malformed, from another run, or not for this peer; ``reason`` is the short
    name its drop is counted under (summary.json): oversized, malformed, foreign, wrong source."""

    def __init__(self, message: str, reason: str = "malformed"):
        super().__init__(message)
        self.reason = reason


def _short(value, limit: int = 40) -> str:
    """``repr(value)`` cut to ``limit`` characters: error messages quote what arrived, never 60 kB of it."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + "..."


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


CONTROLLER = -2  # the source rank of control commands, and the destination of their acks
VIEWER = -1      # the destination of framelets and of rank 0's "end" (nodes/viewer.py)


def control_key(run: str) -> str:
    return f"sph/{run}/control"


def ack_key(run: str) -> str:
    """Rank 0's answers to control commands (nodes/control.py), one per command id."""
    return f"sph/{run}/ack"


def rank_from_key(key: str) -> int:
    """The last segment of a key expression as a rank (``alive`` and ``halo`` keys)."""
    return int(str(key).rsplit("/", 1)[-1])


def is_phase(name) -> bool:
    """Whether ``name`` can be a message's phase (as ``decode`` checks it)."""
    return isinstance(name, str) and bool(_NAME.match(name))


def is_int(value) -> bool:
    """A JSON integer (``True`` is not one, though Python says it is an int)."""
    return isinstance(value, int) and not isinstance(value, bool)


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


def _flat_json(raw: bytes):
    """The header's JSON, refused before parsing if its brackets nest deeper than the schema's."""
    text = raw.decode()
    depth = deepest = 0
    for bracket in _BRACKET.findall(_STRING.sub('""', text)):
        depth += 1 if bracket in "[{" else -1
        deepest = max(deepest, depth)
        if deepest > _MAX_DEPTH:
            raise WireError(f"header nests brackets deeper than {_MAX_DEPTH} levels")
    return json.loads(text)


def _read_header(view: memoryview, max_bytes: int) -> tuple[dict, int]:
    """The header of a message, checked for shape (not for meaning), and where its arrays start;
    WireError if the message is too long, not framed like ours, or its header not the flat schema."""
    if len(view) > max_bytes:
        raise WireError(f"message of {len(view)} bytes exceeds the limit of {max_bytes} bytes", "oversized")
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
        head = _flat_json(bytes(view[_PREFIX.size:_PREFIX.size + hlen]))
    except ValueError as e:  # json.JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise WireError(f"unreadable header: {e}") from None
    if not isinstance(head, dict):
        raise WireError(f"header is a JSON {type(head).__name__}, not an object")
    if set(head) != _FIELDS:
        raise WireError(f"header fields {_short(sorted(head), 80)}, expected {sorted(_FIELDS)}")
    return head, _PREFIX.size + hlen


def decode(data: bytes, run: str, dest: int, world: int, sources=None,
           max_bytes: int = MAX_MESSAGE) -> tuple[int, tuple, dict]:
    """(source, (step, phase), arrays) of a message for peer ``dest`` of run ``run`` with ``world``
    peers (or from one of ``sources``); raises WireError if anything does not fit."""
    view = memoryview(data)
    head, offset = _read_header(view, max_bytes)
    msg_run, step, phase = head["run"], head["step"], head["phase"]
    source, msg_dest, table = head["source"], head["dest"], head["arrays"]
    if msg_run != run:
        raise WireError(f"message of run {_short(msg_run)}, this is run {run!r}", "foreign")
    if not is_int(msg_dest) or msg_dest != dest:
        raise WireError(f"message for peer {_short(msg_dest)} delivered to peer {dest}", "foreign")
    if not is_int(source):
        raise WireError(f"source rank {_short(source)} is not an integer")
    if sources is not None:
        if source not in sources:
            raise WireError(f"source {source!r} is not one of {sorted(sources)}", "wrong source")
    elif not (0 <= source < world and source != dest):
        raise WireError(f"source rank {source!r} is not another peer of this {world}-peer run", "wrong source")
    if not (is_int(step) and -1 <= step <= MAX_STEP) or not is_phase(phase):
        raise WireError(f"bad step {_short(step)} or phase {_short(phase)}")
    if not isinstance(table, list):
        raise WireError("array table is not a list")
    if len(table) > MAX_ARRAYS:
        raise WireError(f"{len(table)} arrays in one message, at most {MAX_ARRAYS}")
    arrays = {}
    for entry in table:
        if not (isinstance(entry, list) and len(entry) == 3):
            raise WireError(f"bad array entry {_short(entry, 80)}")
        name, dtype, shape = entry
        if not (isinstance(name, str) and _NAME.match(name)) or name in arrays or not (
                isinstance(dtype, str) and dtype in DTYPES):
            raise WireError(f"bad array name {_short(name)} or dtype {_short(dtype)}")
        if not (isinstance(shape, list) and len(shape) <= 4 and all(is_int(d) and 0 <= d <= len(view) for d in shape)):
            raise WireError(f"array {name!r}: bad shape {_short(shape, 80)}")
        nbytes = math.prod(shape) * np.dtype(dtype).itemsize
        if offset + nbytes > len(view):
            raise WireError(f"array {name!r} ({nbytes} bytes) runs past the end of the message")
        arrays[name] = np.frombuffer(view, dtype=dtype, count=math.prod(shape), offset=offset).reshape(shape)
        offset += nbytes
    if offset != len(view):
        raise WireError(f"{len(view) - offset} bytes left over after the arrays")
    return source, (step, phase), arrays
