"""Run outputs (the contract of docs/USAGE.md): summary.json, final.npz and the resolved scene.

Files are written to a temporary name in the output folder and renamed into place, so a crash or a
Ctrl-C never leaves a half-written file under the final name.
"""
from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np
import tomli_w


def _atomic_write(path: Path, write):
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; outputs get the usual permissions
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_json(path: Path, value):
    """``value`` as indented JSON, whole or not at all."""
    _atomic_write(path, lambda f: f.write((json.dumps(value, indent=2, sort_keys=False) + "\n").encode()))


def write_summary(path: Path, summary: dict):
    write_json(path, summary)


def write_final(path: Path, arrays: dict):
    """final.npz: id (n,) int64, x (n,3), v (n,3), rho (n,), rows sorted by id (x in world
    coordinates: float64 for a scene run relative to its own origin, sphcore.scene.scene_origin)."""
    _atomic_write(path, lambda f: np.savez(f, **arrays))


def write_scene(path: Path, scene_dict: dict):
    _atomic_write(path, lambda f: f.write(tomli_w.dumps(scene_dict).encode()))
