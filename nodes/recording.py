"""Reading a Rerun recording (.rrd) back: which entities it holds at which steps, and the images.

Used by the tests (a recorded run holds every entity for every rendered step) and by
scripts/screenshots.py (PNG of a composited frame from a recording).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np


def entity_steps(path: Path) -> dict[str, list]:
    """{entity path: sorted steps it was logged at ([] for static entities)}."""
    from rerun.chunk import RrdReader
    out = {}
    for chunk in RrdReader(str(path)).stream():
        batch = chunk.to_record_batch()
        steps = batch.column("step").to_pylist() if "step" in batch.schema.names else []
        out.setdefault(chunk.entity_path, set()).update(s for s in steps if s is not None)
    return {k: sorted(v) for k, v in out.items()}


def images(path: Path, entity: str = "/composite/rgb") -> dict[int, np.ndarray]:
    """{step: (H, W, 3) uint8} of an RGB image entity."""
    from rerun.chunk import RrdReader
    out = {}
    for chunk in RrdReader(str(path)).stream():
        if chunk.entity_path != entity:
            continue
        batch = chunk.to_record_batch()
        for step, buf, fmt in zip(batch.column("step").to_pylist(), batch.column("Image:buffer").to_pylist(),
                                  batch.column("Image:format").to_pylist()):
            f = fmt[0] if isinstance(fmt, list) else fmt
            data = buf[0] if buf and isinstance(buf[0], list) else buf
            out[step] = np.asarray(data, dtype=np.uint8).reshape(f["height"], f["width"], 3)
    return out


def text_logs(path: Path, entity: str) -> list[str]:
    from rerun.chunk import RrdReader
    out = []
    for chunk in RrdReader(str(path)).stream():
        if chunk.entity_path == entity:
            batch = chunk.to_record_batch()
            for name in batch.schema.names:
                if name.endswith(":text"):
                    out += [t[0] if isinstance(t, list) else t for t in batch.column(name).to_pylist()]
    return out
