"""Reading a Rerun recording (.rrd) back: which entities it holds at which steps, and the images.

Used by the tests (a recorded run holds every entity for every rendered step, its blueprint shows
the composite's RGB) and by scripts/screenshots.py (PNG of a composited frame from a recording).
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


def _first(value):
    """The one value of a one-element list (Rerun's columns hold a list per row), else the value."""
    return value[0] if isinstance(value, list) and len(value) == 1 else value


def images(path: Path, entity: str = "/composite/rgb") -> dict[int, np.ndarray]:
    """{step: (H, W, 3) uint8} of an RGB image entity (raw, or encoded as JPEG / PNG)."""
    return {step: image for step, image in _image_rows(path, entity, "Image", "EncodedImage")}


def depth_images(path: Path, entity: str = "/composite/depth") -> dict[int, np.ndarray]:
    """{step: (H, W) float32 depth in m, 0 where empty} of a depth image entity (16-bit PNG + meter)."""
    return {step: image for step, image in _image_rows(path, entity, "DepthImage", "EncodedDepthImage")}


def _image_rows(path: Path, entity: str, raw: str, encoded: str):
    import io

    from PIL import Image
    from rerun.chunk import RrdReader
    for chunk in RrdReader(str(path)).stream():
        if chunk.entity_path != entity:
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        steps = batch.column("step").to_pylist()
        if f"{raw}:buffer" in names:
            for step, buf, fmt in zip(steps, batch.column(f"{raw}:buffer").to_pylist(),
                                      batch.column(f"{raw}:format").to_pylist()):
                f = _first(fmt)
                data = np.asarray(_first(buf), dtype=np.uint8)
                if raw == "Image":
                    yield step, data.reshape(f["height"], f["width"], 3)
                else:
                    yield step, data.view(np.float32).reshape(f["height"], f["width"])
        elif f"{encoded}:blob" in names:
            meter_column = f"{encoded}:meter"
            meters = batch.column(meter_column).to_pylist() if meter_column in names else [None] * len(steps)
            for step, blob, meter in zip(steps, batch.column(f"{encoded}:blob").to_pylist(), meters):
                data = _first(blob)
                picture = np.asarray(Image.open(io.BytesIO(bytes(data))))
                if raw == "Image":
                    yield step, picture[..., :3] if picture.ndim == 3 else np.repeat(picture[..., None], 3, axis=2)
                else:
                    m = _first(meter)
                    m = m[0] if isinstance(m, list) else m
                    yield step, (picture.astype(np.float32) / np.float32(m or 1.0))


def blueprint(path: Path) -> dict:
    """The recording's (first) blueprint: {"views": [{"kind", "name", "origin", "hidden": [entity, ...],
    "contents": [query, ...]}], "containers": [{"kind", "shares"}]} (views in no particular order)."""
    from rerun.chunk import RrdReader
    reader = RrdReader(str(path))
    stores = reader.blueprints()
    if not stores:
        return {"views": [], "containers": []}
    views, containers = {}, []
    for chunk in reader.stream(store=stores[0]):
        batch = chunk.to_record_batch()
        row = {n: batch.column(n).to_pylist()[-1] for n in batch.schema.names
               if ":" in n and not n.startswith("rerun.controls")}
        parts = chunk.entity_path.strip("/").split("/")
        if parts[0] == "view" and len(parts) == 2:
            v = views.setdefault(parts[1], {"hidden": [], "contents": []})
            v.update(kind=_first(row.get("ViewBlueprint:class_identifier")),
                     name=_first(row.get("ViewBlueprint:display_name")),
                     origin=_first(row.get("ViewBlueprint:space_origin")))
        elif parts[0] == "view" and parts[2:3] == ["ViewContents"]:
            v = views.setdefault(parts[1], {"hidden": [], "contents": []})
            if len(parts) == 3:
                v["contents"] = row.get("ViewContents:query") or []
            elif parts[3] == "overrides" and row.get("EntityBehavior:visible") in ([False], False):
                v["hidden"].append("/" + "/".join(parts[4:-1]))
        elif parts[0] == "container":
            containers.append({"kind": _first(row.get("ContainerBlueprint:container_kind")),
                               "shares": row.get("ContainerBlueprint:col_shares") or row.get(
                                   "ContainerBlueprint:row_shares")})
    return {"views": list(views.values()), "containers": containers}


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


def meshes(path: Path, entity: str = "/fluid/surface") -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """{step: (vertex positions (n, 3) float32, triangle indices (m, 3) int64)} of a Mesh3D entity
    (a cleared step is left out)."""
    from rerun.chunk import RrdReader
    out = {}
    for chunk in RrdReader(str(path)).stream():
        if chunk.entity_path != entity:
            continue
        batch = chunk.to_record_batch()
        if "Mesh3D:vertex_positions" not in batch.schema.names:
            continue
        for step, xyz, tri in zip(batch.column("step").to_pylist(), batch.column("Mesh3D:vertex_positions").to_pylist(),
                                  batch.column("Mesh3D:triangle_indices").to_pylist()):
            if xyz:
                out[step] = (np.asarray(xyz, dtype=np.float32).reshape(-1, 3),
                             np.asarray(tri, dtype=np.int64).reshape(-1, 3))
    return out


def enclosed_volume(vertices: np.ndarray, triangles: np.ndarray) -> float:
    """The volume inside a closed triangle mesh (m^3), by the divergence theorem (the sum of the
    signed tetrahedra from the origin to each triangle); its sign says which way the faces turn."""
    a, b, c = (vertices[triangles[:, k]].astype(np.float64) for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)
