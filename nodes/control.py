"""The control channel: steer a running run, one process or many peers, without breaking its
determinism.

A controller (``sph control``) publishes a command with a random id to ``sph/<run>/control`` (with
access control, only the controller's identity may publish there); rank 0 (the only process of a
single-process run started with ``--control``) subscribes, validates it against the scene and answers
on ``sph/<run>/ack`` with the same id: "accepted" and the step N after which every peer applies it,
or "rejected" and the reason. In a run of several peers, accepted commands are announced to every
peer inside rank 0's step reduction message (the one message every peer receives from rank 0 in
every step); the other peers check what they are announced (``check_announced``) and all apply it
after the same step, so the run stays identical on every peer (and reproducible from the recording,
where the viewer logs each applied command under ``control``). nodes/peer.py ``Controls`` does this.

A command message carries two byte arrays, ``id`` (8-32 lowercase hex digits) and ``command`` (the
command line as typed); an ack carries ``id``, ``result`` (accepted | rejected) and ``reason``, with
the step in the message header.

Commands:

    pause | resume                    hold after this step (peers wait, their links stay up) / go on
    step N                            run N more steps, then hold (from a pause, or while running)
    reset                             back to the initial particles (t = 0); the run and its step
                                      count go on
    checkpoint                        write a checkpoint of this step now (the run's checkpoint folder)
    camera NAME                       switch the camera of the rendered frames
    color_by speed|density|pressure|rank
    set KEY=VALUE                     a key of ``SETTABLE`` (sphcore/scene.py: the keys declared LIVE),
                                      validated like the scene file
"""
from __future__ import annotations

import re
import secrets

import numpy as np

from sphcore.scene import SceneError, key_control, live_change, live_keys, LIVE

SETTABLE = tuple(live_keys())  # the scene keys that may change during a run, declared in sphcore/scene.py
COLOURS = ("speed", "density", "pressure", "rank")
MAX_TEXT = 1000           # bytes of one command line
MAX_MESSAGE = 4096        # bytes of a command message on the wire (header included)
MAX_PENDING = 64          # commands waiting for rank 0's next step
MAX_STEP_COUNT = 10**9    # step N: at most this many steps
OPS = ("pause", "resume", "step", "reset", "checkpoint", "camera", "color_by", "set")
# what rank 0 announces to the other peers (resume and step N only end or schedule a pause, which
# rank 0 announces itself)
ANNOUNCED = ("pause", "camera", "color_by", "set", "reset", "checkpoint")
_ID = re.compile(r"^[0-9a-f]{8,32}$")
_COUNT = re.compile(r"^[0-9]{1,10}$")
_FIELDS = {"pause": (), "camera": ("name",), "color_by": ("quantity",), "set": ("key", "value"), "reset": (),
           "checkpoint": ()}
USAGE = (f"pause, resume, step N, reset, checkpoint, camera NAME, color_by {'|'.join(COLOURS)}, or set KEY=VALUE "
         "(KEY: see sph control --help)")


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
    """A command line as typed (``set forces.external=[1,0,0]``) -> {"op": ..., ...}; ValueError
    naming what is wrong and what is allowed if it is not a command (a ``set`` of a key that cannot
    change during a run names the reason)."""
    words = text.strip().split(None, 1)
    if not words:
        raise ValueError(f"empty command: use {USAGE}")
    op, rest = words[0], (words[1].strip() if len(words) > 1 else "")
    if op in ("pause", "resume", "reset", "checkpoint"):
        if rest:
            raise ValueError(f"{op} takes no argument, got {rest[:40]!r}")
        return {"op": op}
    if op == "step":
        if not _COUNT.match(rest) or not 1 <= int(rest) <= MAX_STEP_COUNT:
            raise ValueError(f"step {rest[:40]!r}: expected a number of steps, 1 to {MAX_STEP_COUNT}")
        return {"op": "step", "count": int(rest)}
    if op == "camera" and rest:
        return {"op": "camera", "name": rest}
    if op == "color_by":
        if rest not in COLOURS:
            raise ValueError(f"color_by {rest[:40]!r}: allowed {', '.join(COLOURS)}")
        return {"op": "color_by", "quantity": rest}
    if op == "set":
        if "=" not in rest:
            raise ValueError(f"set {rest[:60]!r}: expected set KEY=VALUE, KEY one of {', '.join(SETTABLE)}")
        key, value = rest.split("=", 1)
        key = key.strip()
        try:
            control = key_control(key)
        except SceneError as e:
            raise ValueError(f"set {key[:60]}: not a scene key ({e})") from None
        if control is not LIVE:
            raise ValueError(f"set {key}: not settable at run time: it {control} (settable: {', '.join(SETTABLE)})")
        return {"op": "set", "key": key, "value": value.strip()}
    raise ValueError(f"unknown command {text[:60]!r}: use {USAGE}")


def validate(scene, cmd: dict, cameras, sim=None, can_checkpoint: bool = True):
    """Check a command against ``scene`` (values through the scene's own validation; with ``sim``,
    also that a ``set`` changes nothing but what a running step can follow: ``Simulation.changed_model``).
    Returns (the command with a typed value, the scene after it). Raises ValueError naming the
    problem."""
    op = cmd["op"]
    if op == "camera" and cmd["name"] not in cameras:
        raise ValueError(f"camera {cmd['name']!r}: allowed {', '.join(repr(c) for c in cameras)}")
    if op == "checkpoint" and not can_checkpoint:
        raise ValueError("checkpoint: this run has no output folder to write checkpoints into")
    if op != "set":
        return cmd, scene
    text = f"{cmd['key']}={cmd['value']}" if isinstance(cmd["value"], str) else None
    try:
        if text is None:  # an announced value (JSON): written back as TOML, read like the scene file
            from sphcore.scene import _toml_exact
            value = cmd["value"]
            if not isinstance(value, (int, float, bool, str, list)) or (
                    isinstance(value, list) and not all(isinstance(e, (int, float, bool)) for e in value)):
                raise ValueError(f"set {cmd['key']}: {str(value)[:60]} is not a scene value")
            text = f"{cmd['key']}={_toml_exact(value)}"
        key, new = live_change(scene, text)
    except SceneError as e:
        raise ValueError(str(e)) from None
    section, name = key.split(".")
    value = getattr(getattr(new, section), name)
    if sim is not None and new is not scene:
        try:
            sim.changed_model(new)
        except ValueError as e:
            raise ValueError(f"set {key} = {_shown(value)}: {e}") from None
    return dict(cmd, key=key, value=list(value) if isinstance(value, tuple) else value), new  # as JSON carries it


def _shown(value) -> str:
    return str(list(value)) if isinstance(value, tuple) else repr(value)


def describe(cmd: dict) -> str:
    if cmd["op"] == "set":
        return f"set {cmd['key']} = {cmd['value']}"
    return " ".join(str(v) for v in cmd.values())


def check_announced(scene, commands, cameras, sim=None, ops=ANNOUNCED) -> list:
    """What a peer is announced by rank 0 must be commands rank 0 could have accepted: a list of
    dicts with exactly the fields of their op (one of ``ops``), values that pass ``validate`` in
    order (each against the scene the ones before it leave). Raises ValueError naming the first that
    is not (the peer then drops the message, sphcore/halo.py)."""
    if not isinstance(commands, list):
        raise ValueError(f"announced commands are a {type(commands).__name__}, not a list")
    for cmd in commands:
        op = cmd.get("op") if isinstance(cmd, dict) else None
        if op not in ops or set(cmd) != {"op", *_FIELDS[op]}:
            raise ValueError(f"announced command {str(cmd)[:80]}: not one of {', '.join(ops)} with its fields")
        if op == "camera" and not isinstance(cmd["name"], str):
            raise ValueError(f"announced camera {str(cmd['name'])[:40]}: not a name")
        if op == "color_by" and cmd["quantity"] not in COLOURS:
            raise ValueError(f"announced color_by {str(cmd['quantity'])[:40]}: allowed {', '.join(COLOURS)}")
        if op == "set" and (not isinstance(cmd["key"], str) or cmd["key"] not in SETTABLE):
            raise ValueError(f"announced set {str(cmd['key'])[:60]}: not settable at run time")
        checked, scene = validate(scene, cmd, cameras, sim)
        if op == "set" and checked["value"] != cmd["value"]:
            raise ValueError(f"announced set {cmd['key']} = {str(cmd['value'])[:60]}: not a validated value")
    return commands
