"""The control channel: change a running multi-peer run without breaking its determinism.

A controller (``sph control``) publishes a command with a random id to ``sph/<run>/control`` (with
access control, only the controller's identity may publish there); rank 0 subscribes, validates it
against the scene and answers on ``sph/<run>/ack`` with the same id: "accepted" and the step N after
which every peer applies it, or "rejected" and the reason. Accepted commands are announced to every
peer inside rank 0's step reduction message (the one message every peer receives from rank 0 in
every step); the other peers check what they are announced (``check_announced``) and all apply it
after the same step, so the run stays identical on every peer (and reproducible from the recording,
where the viewer logs each applied command under ``control``).

A command message carries two byte arrays, ``id`` (8-32 lowercase hex digits) and ``command`` (the
command line as typed); an ack carries ``id``, ``result`` (accepted | rejected) and ``reason``, with
the step in the message header.

Commands:

    pause | resume                    stop stepping / go on (peers wait, their links stay up)
    camera NAME                       switch the camera of the rendered frames
    color_by speed|density|pressure|rank
    set KEY=VALUE                     one of SETTABLE below, validated like the scene file
"""
from __future__ import annotations

import re
import secrets

import numpy as np

SETTABLE = {
    "forces.external": "constant external acceleration (m/s^2), e.g. [2, 0, 0]",
    "forces.gravity": "gravity (m/s^2)",
    "sph.alpha": "artificial viscosity coefficient",
    "sph.nu": "kinematic viscosity (m^2/s)",
    "boundary.friction": "fraction of tangential velocity removed on wall contact (damping)",
    "boundary.restitution": "normal velocity kept on wall contact",
}
COLOURS = ("speed", "density", "pressure", "rank")
MAX_TEXT = 1000           # bytes of one command line
MAX_MESSAGE = 4096        # bytes of a command message on the wire (header included)
MAX_PENDING = 64          # commands waiting for rank 0's next step
ANNOUNCED = ("pause", "camera", "color_by", "set")  # what rank 0 announces (resume only ends a pause)
_ID = re.compile(r"^[0-9a-f]{8,32}$")
_FIELDS = {"pause": (), "camera": ("name",), "color_by": ("quantity",), "set": ("key", "value")}


def new_id() -> str:
    """A fresh command id (the controller matches rank 0's ack to its command by it)."""
    return secrets.token_hex(8)


def _text(array, what: str, limit: int) -> str:
    if array.dtype != np.uint8 or array.ndim != 1 or len(array) > limit:
        raise ValueError(f"{what}: expected at most {limit} bytes of text, got {array.dtype}{list(array.shape)}")
    return bytes(array).decode()  # UnicodeDecodeError is a ValueError


def _bytes_of(text: str) -> np.ndarray:
    return np.frombuffer(text.encode(), dtype=np.uint8)


def command_arrays(command_id: str, text: str) -> dict:
    """The arrays of a command message."""
    return {"id": _bytes_of(command_id), "command": _bytes_of(text)}


def read_command(phase: str, arrays: dict) -> dict:
    """{"id", "text"} of a command message (decoded by ``wire.decode``); ValueError if it is not one.
    The text is parsed and validated later, by rank 0's step loop, which acknowledges it."""
    if phase != "control" or set(arrays) != {"id", "command"}:
        raise ValueError(f"phase {phase!r} with arrays {sorted(arrays)[:8]}, expected 'control' with id, command")
    command_id = _text(arrays["id"], "id", 32)
    if not _ID.match(command_id):
        raise ValueError(f"command id {command_id!r}: expected 8-32 lowercase hex digits")
    return {"id": command_id, "text": _text(arrays["command"], "command", MAX_TEXT)}


def ack_arrays(command_id: str, result: str, reason: str = "") -> dict:
    """The arrays of rank 0's answer to command ``command_id``."""
    if result not in ("accepted", "rejected"):
        raise ValueError(f"ack result {result!r}: accepted or rejected")
    return {"id": _bytes_of(command_id), "result": _bytes_of(result),
            "reason": _bytes_of(reason.encode()[:MAX_TEXT].decode(errors="ignore"))}


def read_ack(arrays: dict) -> dict:
    """{"id", "result", "reason"} of an ack message; ValueError if it is not one."""
    if set(arrays) != {"id", "result", "reason"}:
        raise ValueError(f"ack arrays {sorted(arrays)[:8]}, expected id, result, reason")
    ack = {k: _text(arrays[k], k, MAX_TEXT) for k in ("id", "result", "reason")}
    if ack["result"] not in ("accepted", "rejected"):
        raise ValueError(f"ack result {ack['result']!r}")
    return ack


def parse(text: str) -> dict:
    """A command line as typed (``set forces.external=[1,0,0]``) -> {"op": ..., ...}; ValueError if
    it is not a command."""
    words = text.strip().split(None, 1)
    if not words:
        raise ValueError("empty command")
    op, rest = words[0], (words[1].strip() if len(words) > 1 else "")
    if op in ("pause", "resume") and not rest:
        return {"op": op}
    if op == "camera" and rest:
        return {"op": "camera", "name": rest}
    if op == "color_by" and rest in COLOURS:
        return {"op": "color_by", "quantity": rest}
    if op == "set" and "=" in rest:
        key, value = rest.split("=", 1)
        key = key.strip()
        if key not in SETTABLE:
            raise ValueError(f"set {key}: not settable at run time (allowed: {', '.join(SETTABLE)})")
        return {"op": "set", "key": key, "value": value.strip()}
    raise ValueError(f"unknown command {text!r}: use pause, resume, camera NAME, color_by "
                     f"{'|'.join(COLOURS)}, or set KEY=VALUE with KEY one of {', '.join(SETTABLE)}")


def validate(scene, cmd: dict, cameras) -> dict:
    """Check a command against the scene (values through the scene's own validation); returns it with
    a typed value. Raises ValueError naming the problem."""
    if cmd["op"] == "camera" and cmd["name"] not in cameras:
        raise ValueError(f"camera {cmd['name']!r}: allowed {', '.join(repr(c) for c in cameras)}")
    if cmd["op"] == "set":
        from sphcore.scene import SceneError, apply_override, parse_override, scene_from_dict
        data = scene.to_dict()
        text = f"{cmd['key']}={cmd['value']}"
        try:
            path, value = parse_override(text)
            apply_override(data, path, value, text)
            new = scene_from_dict(data)
        except SceneError as e:
            raise ValueError(str(e)) from None
        section, key = cmd["key"].split(".")
        value = getattr(getattr(new, section), key)
        cmd = dict(cmd, value=list(value) if isinstance(value, tuple) else value)  # as JSON carries it
    return cmd


def describe(cmd: dict) -> str:
    if cmd["op"] == "set":
        return f"set {cmd['key']} = {cmd['value']}"
    return " ".join(str(v) for v in cmd.values())


def check_announced(scene, commands, cameras) -> list:
    """What a peer is announced in rank 0's reduction must be commands rank 0 could have accepted:
    a list of dicts with exactly the fields of their op, values that pass ``validate``. Raises
    ValueError naming the first that is not (the peer then drops the message, sphcore/halo.py)."""
    if not isinstance(commands, list):
        raise ValueError(f"announced commands are a {type(commands).__name__}, not a list")
    for cmd in commands:
        op = cmd.get("op") if isinstance(cmd, dict) else None
        if op not in ANNOUNCED or set(cmd) != {"op", *_FIELDS[op]}:
            raise ValueError(f"announced command {str(cmd)[:80]}: not one of {', '.join(ANNOUNCED)} with its fields")
        if op == "camera" and not isinstance(cmd["name"], str):
            raise ValueError(f"announced camera {cmd['name']!r}: not a name")
        if op == "color_by" and cmd["quantity"] not in COLOURS:
            raise ValueError(f"announced color_by {cmd['quantity']!r}: allowed {', '.join(COLOURS)}")
        if op == "set" and cmd["key"] not in SETTABLE:
            raise ValueError(f"announced set {cmd['key']!r}: not settable at run time")
        checked = validate(scene, cmd, cameras)
        if op == "set" and checked["value"] != cmd["value"]:
            raise ValueError(f"announced set {cmd['key']} = {cmd['value']!r}: not a validated value")
    return commands
