"""The control channel: change a running multi-peer run without breaking its determinism.

A controller (``sph control``) publishes a command to ``sph/<run>/control``; rank 0 subscribes,
validates it and announces it to every peer inside its step-s reduction message (the one message
every peer receives from rank 0 in every step). All peers apply it after step s, so the run stays
identical on every peer (and reproducible from the recording, where the viewer logs each applied
command under ``control``).

Commands:

    pause | resume                    stop stepping / go on (peers wait, their links stay up)
    camera NAME                       switch the camera of the rendered frames
    color_by speed|density|pressure|rank
    set KEY=VALUE                     one of SETTABLE below, validated like the scene file
"""
from __future__ import annotations

SETTABLE = {
    "forces.external": "constant external acceleration (m/s^2), e.g. [2, 0, 0]",
    "forces.gravity": "gravity (m/s^2)",
    "sph.alpha": "artificial viscosity coefficient",
    "sph.nu": "kinematic viscosity (m^2/s)",
    "boundary.friction": "fraction of tangential velocity removed on wall contact (damping)",
    "boundary.restitution": "normal velocity kept on wall contact",
}
COLOURS = ("speed", "density", "pressure", "rank")


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
