"""Checkpoints: the full state of a run at the end of a step, from which a run continues exactly.

Layout (one folder per checkpoint, under OUT/checkpoints/):

    step_00000300/peer_0000.npz     a peer's owned particles: id, x, v, m (its dtype)
    step_00000300/peer_0001.npz     ...one file per peer of the run that wrote it
    step_00000300/manifest.json     format, step, t, dt, dt_prev, counters, precision, the resolved
                                    scene and its SHA-256, the parts with their particle counts and
                                    SHA-256 (every field checked on load: MANIFEST_SCHEMA)
    latest                          the name of the newest complete checkpoint folder

Everything a step carries to the next is saved: positions, velocities (half-step velocities for
leapfrog), masses, ids, t, the step index, dt_prev (leapfrog's combined kick) and the counters
of summary.json. Density, pressure and accelerations are recomputed by the next step, so they
are not saved. Every peer writes its own part; rank 0 writes the manifest after all parts are in,
into a temporary folder that is renamed into place, then rewrites ``latest`` (atomic rename): a
crash mid-write never leaves a corrupt "latest". A resumed run may use any number of peers: each
peer reads all parts and keeps the particles of its block.

``restore`` checks what only the run knows before it changes anything: every extra_* array is one
the run's solver carries, of its shape and dtype, and every mass is within MASS_FACTOR of the scene's
particle mass.

A part or manifest that cannot be written (a full disk: ENOSPC, or any OSError) raises
``CheckpointWriteError``, which names the path, the space the file needs and the space free; what
was half-written is removed first. The runs (launch/run.py, nodes/peer.py) log it, skip that
checkpoint and go on: ``latest`` keeps naming the last good one. ``latest()`` is what a launcher
restarts a run from (launch/supervise.py).
"""
from __future__ import annotations

import copy
import hashlib
import json
import math
import os
import re
import shutil
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sphcore.state import (CARRIED, EXTRA_PREFIX, ROW_SHAPE, ParticleState, carried_layout, is_carried,
                           merge_by_id)

FORMAT = "sphfluid-checkpoint-1"


class CheckpointError(ValueError):
    """A checkpoint that is missing, incomplete, corrupt or does not fit the run."""


def folder_name(step: int) -> str:
    return f"step_{step:08d}"


def part_name(rank: int) -> str:
    return f"peer_{rank:04d}.npz"


_PART = re.compile(r"^peer_\d{4,}\.npz$")


def is_part_name(name: str) -> bool:
    """A part's file name as part_name writes it: a bare peer_NNNN.npz, no folder in it."""
    return bool(_PART.match(name))


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def staging(root: Path, step: int) -> Path:
    """The temporary folder parts of ``step`` are written into (renamed when complete)."""
    return Path(root) / f".{folder_name(step)}.partial"


class CheckpointWriteError(RuntimeError):
    """A checkpoint (part or manifest) that could not be written (disk full, permissions, ...): the
    message names the path, the space it needs and the space free; what was half-written is gone."""


def _size_text(nbytes: float) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if nbytes >= scale:
            return f"{nbytes / scale:.3g} {unit}"
    return f"{int(nbytes)} B"


def _free_bytes(path: Path) -> int | None:
    for folder in (Path(path), *Path(path).parents):
        if folder.exists():
            try:
                return shutil.disk_usage(folder).free
            except OSError:
                return None
    return None


def _write_error(step: int, path: Path, error: OSError, need: int) -> CheckpointWriteError:
    free = _free_bytes(path.parent)
    space = f"needs ~{_size_text(need)}, " + (f"{_size_text(free)} free there" if free is not None else
                                               "free space unknown")
    return CheckpointWriteError(f"checkpoint step {step}: cannot write {path}: {error.strerror or error} "
                                f"({space})")


def part_arrays(sim) -> dict:
    """The arrays of this peer's part: the carried arrays of its owned rows (state.CARRIED, extra_*)."""
    s = sim.state
    return s.carried_arrays(s.n_owned)


def _write_npz(file, arrays: dict):
    np.savez(file, **arrays)


def write_part(root: Path, step: int, rank: int, sim) -> dict:
    """Write this peer's owned particles; returns its manifest entry. CheckpointWriteError if it
    cannot be written (this peer's partial file is removed first; the shared staging folder is
    left for rank 0 to discard)."""
    folder = staging(root, step)
    arrays = part_arrays(sim)
    path = folder / part_name(rank)
    tmp = folder / f".{part_name(rank)}.tmp"
    need = sum(a.nbytes for a in arrays.values()) + 512 * (len(arrays) + 1)  # + the zip's headers
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as f:
            _write_npz(f, arrays)
        os.replace(tmp, path)
        digest = _sha256(path)
    except OSError as e:
        for leftover in (tmp, path):
            leftover.unlink(missing_ok=True)
        # The staging folder stays: another peer may have made it and be about to write its part
        # into it (removing it here, even empty, failed that peer's write too). Rank 0 removes the
        # folder once every peer has answered (Checkpoints.save -> discard).
        raise _write_error(step, path, e, need) from None
    return {"file": part_name(rank), "particles": len(arrays["id"]), "sha256": digest}


def discard(root: Path, step: int):
    """Remove the staging folder of ``step`` (a part failed: the checkpoint is not committed)."""
    shutil.rmtree(staging(root, step), ignore_errors=True)


def remove_partial(root: Path):
    """Remove every staging folder under ``root`` (left by processes that were stopped mid-write)."""
    for folder in Path(root).glob(".step_*.partial"):
        shutil.rmtree(folder, ignore_errors=True)


def sim_info(sim) -> dict:
    return {"step": sim.step_index, "t": sim.t, "dt": sim.dt, "dt_prev": sim.dt_prev, "leaks": sim.leaks,
            "max_neighbours": sim.max_neighbours, "max_compression": sim.max_compression,
            "limit_counts": sim.limit_counts, "last_limit": sim.last_limit, "precision": sim.precision,
            "particles": sim.n_particles, "bodies": [body.state() for body in sim.model.walls.bodies],
            "origin": list(sim.scene.origin)}


def scene_digest(scene_dict: dict) -> str:
    """SHA-256 of a resolved scene's canonical JSON: a manifest whose scene was edited (a changed
    gravity would run on without a word) no longer matches it."""
    text = json.dumps(scene_dict, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


def commit(root: Path, step: int, info: dict, scene_dict: dict, parts: list[dict], keep: int = 2):
    """All parts of ``step`` are written: add the manifest, rename the folder into place, point
    ``latest`` at it and remove all but the newest ``keep`` checkpoints. CheckpointWriteError if
    that fails: the step's folder is removed and ``latest`` still names the previous checkpoint."""
    root = Path(root)
    folder = staging(root, step)
    final = root / folder_name(step)
    manifest = dict(info, format=FORMAT, scene=scene_dict, scene_sha256=scene_digest(scene_dict), parts=parts)
    text = json.dumps(manifest, indent=1) + "\n"
    path = folder / "manifest.json"
    try:
        tmp = folder / ".manifest.json.tmp"
        tmp.write_text(text)
        os.replace(tmp, path)
        if final.exists():
            shutil.rmtree(final)
        os.replace(folder, final)
        path = root / "latest"
        tmp = root / ".latest.tmp"
        tmp.write_text(folder_name(step) + "\n")
        os.replace(tmp, path)
    except OSError as e:
        (root / ".latest.tmp").unlink(missing_ok=True)
        shutil.rmtree(folder, ignore_errors=True)
        if _named_latest(root) != folder_name(step):
            shutil.rmtree(final, ignore_errors=True)
        raise _write_error(step, path, e, len(text) + 64) from None
    # the newest by commit time, not by step: an earlier run's checkpoints in the same folder may have
    # higher steps, and the one just committed is always kept
    done = sorted((p for p in root.glob("step_*") if p.is_dir() and p != final), key=_committed_at)
    for old in done[:-(keep - 1)] if keep > 1 else done:
        shutil.rmtree(old, ignore_errors=True)


def _committed_at(folder: Path) -> float:
    try:
        return (folder / "manifest.json").stat().st_mtime
    except OSError:
        return 0.0


def _named_latest(root: Path) -> str | None:
    try:
        return (Path(root) / "latest").read_text().strip()
    except (OSError, ValueError):  # ValueError: not UTF-8 text (UnicodeDecodeError)
        return None


@dataclass
class Checkpoint:
    path: Path
    manifest: dict
    arrays: dict  # id, x, v, m (and extra_* carried arrays) of all particles, sorted by id

    @property
    def step(self) -> int:
        return int(self.manifest["step"])


_FOLDER = re.compile(r"^step_\d{8,}$")


def _read_latest(latest: Path) -> str:
    """The folder name a ``latest`` file holds (as commit writes it: folder_name(step), one line);
    CheckpointError naming the file if it is unreadable, not UTF-8 text or not such a name (a name
    with a folder in it, e.g. ../.., would make load read outside the checkpoints)."""
    try:
        data = latest.read_bytes()
    except OSError as e:
        raise CheckpointError(f"{latest}: unreadable ({e.strerror or e})") from None
    try:
        name = data.decode("utf-8").strip()
    except UnicodeDecodeError as e:
        raise CheckpointError(f"{latest}: not text (byte 0x{data[e.start]:02x} at offset {e.start} is not UTF-8); "
                              "expected the name of a checkpoint folder, e.g. step_00000300") from None
    if not _FOLDER.match(name):
        raise CheckpointError(f"{latest}: holds {_short(name)}; expected the name of a checkpoint folder, e.g. "
                              "step_00000300")
    return name


def resolve(path: Path) -> Path:
    """A checkpoint folder from a run's OUT folder, its checkpoints/ folder or the folder itself."""
    path = Path(path)
    for root in (path / "checkpoints", path):
        latest = root / "latest"
        if latest.is_file():
            return root / _read_latest(latest)
    if (path / "manifest.json").is_file():
        return path
    raise CheckpointError(f"{str(path)!r}: no checkpoint here (expected OUT/checkpoints/latest, a "
                          "checkpoints/ folder or a step_* folder with manifest.json)")


def latest(path: Path) -> tuple[Path, int] | None:
    """The newest complete checkpoint under ``path`` (as ``resolve`` finds it) and its step, or
    None when there is none yet (or it is unreadable)."""
    try:
        folder = resolve(path)
        return folder, int(json.loads((folder / "manifest.json").read_text())["step"])
    except (CheckpointError, OSError, ValueError, KeyError, TypeError):
        return None


def _integer(lo: int):
    def check(v):
        return isinstance(v, int) and not isinstance(v, bool) and v >= lo
    return check, f"an integer >= {lo}"


def _number(lo: float, hi: float = math.inf, lo_open: bool = False):
    def check(v):
        return (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                and (v > lo if lo_open else v >= lo) and v <= hi)
    return check, f"a finite number in {'(' if lo_open else '['}{lo:g}, {hi:g}]"


def _limit_counts(v):
    from sphcore.timestep import LIMITS
    return isinstance(v, dict) and all(k in LIMITS and _integer(0)[0](n) for k, n in v.items())


def _last_limit(v):
    from sphcore.timestep import LIMITS
    return v == "" or v in LIMITS


_HEX64 = re.compile(r"^[0-9a-f]{64}$")

# The latest time (s) a checkpoint may hold. t is a double: at t the next step adds dt to a number
# whose spacing is about t * 2^-52, so from some t on a step no longer advances the clock (at
# t = 1e20 the spacing is 16384 s and t + dt == t: --until never arrives). Up to 1e9 s the spacing
# is at most 1.2e-7 s, below the steps runs take (time.dt <= 1 s; the CFL limits typically give
# 1e-5 .. 1e-3 s), and no scene gets there by itself: time.steps <= 1e9 steps of time.dt <= 1 s.
T_MAX = 1e9

# How far (either way) a checkpoint's masses may be from its scene's particle mass (Model.mass = rho0 /
# the kernel's lattice sum, about rho0 dx^dim: every particle of a block or an inlet gets it, so a run
# without live changes has no other mass). A live change of fluid.rest_density gives new particles
# (an inlet's, a reset's) the new mass while the others keep theirs, so masses may differ from that
# of the scene saved with the checkpoint, but a factor of a thousand is a damaged file (or a change
# of rho0 the fluid cannot follow: rho / rho0 would sit at 1e3 or 1e-3); such masses underflow rho or
# V = m / rho to 0 in the step (a ZeroDivisionError deep in the compiled passes).
MASS_FACTOR = 1e3

# Every field of manifest.json: (check, what is allowed). A manifest with a field missing, of
# another type or out of range is refused naming the field, its value and what is allowed.
MANIFEST_SCHEMA = {
    "step": _integer(0),
    "t": _number(0.0, T_MAX),
    "dt": _number(0.0, 1.0, lo_open=True),           # time.dt's range: a step of 0 never advances
    "dt_prev": _number(0.0, 1.0),
    "leaks": _integer(0),
    "max_neighbours": _integer(0),
    "max_compression": _number(-math.inf),
    "limit_counts": (_limit_counts, "an object of time-step limit names to integers >= 0"),
    "last_limit": (_last_limit, "a time-step limit name or \"\""),
    "precision": (lambda v: v in ("f32", "f64"), "'f32' or 'f64'"),
    "particles": _integer(1),
    "bodies": (lambda v: isinstance(v, list) and all(
        isinstance(b, list) and len(b) in (9, 24) and all(_number(-math.inf)[0](c) for c in b) for b in v),
               "a list of floating bodies' [x, y, z, u, v, w, ax, ay, az] (finite numbers), each followed by its "
               "orientation (9), angular velocity (3) and angular acceleration (3) if it turns"),
    "origin": (lambda v: isinstance(v, list) and len(v) == 3 and all(_number(-math.inf)[0](c) for c in v),
               "[x, y, z]: the origin of the positions (m, finite numbers)"),
    "scene": (lambda v: isinstance(v, dict), "an object (the resolved scene)"),
    "scene_sha256": (lambda v: isinstance(v, str) and bool(_HEX64.match(v)), "64 hexadecimal digits"),
}


# absent from the checkpoints of versions before floating bodies (and of scenes without), and before
# positions relative to the scene's origin (which then was the world's: scenes near it keep it)
OPTIONAL = ("bodies", "origin")


def _short(value, limit: int = 60) -> str:
    try:
        text = json.dumps(value)
    except (ValueError, RecursionError):
        text = repr(type(value))
    return text if len(text) <= limit else text[: limit - 3] + "..."


def check_manifest(manifest, where: str):
    """The manifest's schema (MANIFEST_SCHEMA, format, parts); CheckpointError names the field."""
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        found = manifest.get("format") if isinstance(manifest, dict) else type(manifest).__name__
        raise CheckpointError(f"{where}: format {found!r}, this version reads {FORMAT!r}")
    for name, (check, allowed) in MANIFEST_SCHEMA.items():
        if name not in manifest and name in OPTIONAL:
            continue
        if name not in manifest:
            raise CheckpointError(f"{where}: {name} is missing (expected {allowed})")
        if not check(manifest[name]):
            raise CheckpointError(f"{where}: {name} = {_short(manifest[name])}: expected {allowed}")
    if scene_digest(manifest["scene"]) != manifest["scene_sha256"]:
        raise CheckpointError(f"{where}: the scene does not match its scene_sha256 (edited after the run wrote "
                              "it?); a changed scene would not continue the run it claims to")
    entries = manifest.get("parts")
    if not (isinstance(entries, list) and entries and all(
            isinstance(e, dict) and isinstance(e.get("file"), str) and is_part_name(e["file"])
            and isinstance(e.get("sha256"), str) and _integer(0)[0](e.get("particles")) for e in entries)):
        raise CheckpointError(f"{where}: 'parts' must list the parts as "
                              "{file: peer_NNNN.npz, particles: integer >= 0, sha256}")
    if len({e["file"] for e in entries}) != len(entries):
        raise CheckpointError(f"{where}: 'parts' lists a part twice")


def _check_part(part: dict, entry: dict, folder: Path, dtype):
    """A part's arrays: the carried ones present, of the manifest's precision, one row per particle,
    finite, positive masses."""
    name = entry["file"]
    missing = [k for k in CARRIED if k not in part]
    if missing:
        raise CheckpointError(f"{folder}: part {name} has no {missing[0]!r} array (a part holds "
                              f"{', '.join(CARRIED)})")
    n = len(part["id"]) if part["id"].ndim == 1 else -1
    if part["id"].dtype != np.int64 or n < 0:
        raise CheckpointError(f"{folder}: part {name}: 'id' is {part['id'].dtype} {part['id'].shape}, expected int64 (n,)")
    for key, values in part.items():
        if key == "id":
            continue
        want = (n,) + ROW_SHAPE[key] if key in ROW_SHAPE else None
        if values.shape[:1] != (n,) or (want is not None and values.shape != want) or values.dtype != dtype:
            raise CheckpointError(f"{folder}: part {name}: {key!r} is {values.dtype} {values.shape}, expected "
                                  f"{np.dtype(dtype).name} {want or (n, '...')}")
        if not np.isfinite(values).all():
            raise CheckpointError(f"{folder}: part {name}: {key!r} holds non-finite values")
    if np.any(part["m"] <= 0):
        raise CheckpointError(f"{folder}: part {name}: 'm' holds masses <= 0")
    tiny = np.finfo(dtype).tiny
    if np.any(part["m"] < tiny):  # subnormal: rho = sum m W and m / rho lose their digits or become 0
        raise CheckpointError(f"{folder}: part {name}: 'm' holds {float(part['m'].min())!r}: masses must be normal "
                              f"{np.dtype(dtype).name} numbers (>= {tiny:.4g} kg)")


def load(path: Path) -> Checkpoint:
    """Read and check a checkpoint; CheckpointError says what is wrong."""
    folder = resolve(path)
    try:
        manifest = json.loads((folder / "manifest.json").read_text())
    except (OSError, ValueError, RecursionError) as e:
        raise CheckpointError(f"{folder}/manifest.json: unreadable ({str(e)[:200]})") from None
    check_manifest(manifest, f"{folder}/manifest.json")
    entries = manifest["parts"]
    dtype = {"f32": np.float32, "f64": np.float64}[manifest["precision"]]
    parts = []
    for entry in entries:
        p = folder / entry["file"]  # a bare peer_NNNN.npz (checked above): never outside the folder
        if not p.is_file():
            raise CheckpointError(f"{folder}: part {entry['file']} is missing")
        if _sha256(p) != entry["sha256"]:
            raise CheckpointError(f"{folder}: part {entry['file']} is corrupt (checksum mismatch)")
        try:
            with np.load(p, allow_pickle=False) as z:
                part = {k: z[k] for k in z.files if is_carried(k)}
        except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as e:  # not a zip, a bad member, pickled
            raise CheckpointError(f"{folder}: part {entry['file']} is unreadable ({str(e)[:120]})") from None
        _check_part(part, entry, folder, dtype)
        if set(part) != set(parts[0] if parts else part):
            raise CheckpointError(f"{folder}: part {entry['file']} holds other arrays than the first part "
                                  f"({', '.join(sorted(part))})")
        if len(part["id"]) != entry["particles"]:
            raise CheckpointError(f"{folder}: part {entry['file']} holds {len(part['id'])} particles, the "
                                  f"manifest says {entry['particles']}")
        parts.append(part)
    arrays = merge_by_id(parts, tuple(parts[0]) if parts else CARRIED)
    if len(arrays["id"]) != manifest["particles"] or np.any(np.diff(arrays["id"]) <= 0):
        raise CheckpointError(f"{folder}: {len(arrays['id'])} particles with duplicates or gaps; the run had "
                              f"{manifest['particles']}")
    return Checkpoint(folder, manifest, arrays)


def _restore_open(sim, ckpt: Checkpoint):
    """A scene with inlets or outlets: the checkpoint's ids must be ones its particles can have at its
    time (sorted, unique); the count and the inflow / outflow totals follow (open_boundary.py)."""
    ids, t = ckpt.arrays["id"], float(ckpt.manifest["t"])
    op = sim.open
    made = op.created(t)
    valid = op.ids_valid(ids, t) and bool(np.all(np.diff(ids) > 0))
    if not valid or len(ids) > op.n_initial + made:
        raise CheckpointError(f"{ckpt.path}: its particle ids are not those its scene's blocks and inlets make by t = "
                              f"{t:.6g} s (or are repeated)")
    sim.n_particles = len(ids)
    op.inflow = made - op.created(0.0)
    op.outflow = op.n_initial + made - len(ids)


def _check_fits_run(sim, ckpt: Checkpoint):
    """The checkpoint's arrays are what this run carries: each extra_* array one the run carries
    (its solver's, sphcore/state.py), of its row shape and dtype (load only knows one row per
    particle: an extra of another shape would reach the compiled passes); and masses within
    MASS_FACTOR of the scene's particle mass."""
    a = ckpt.arrays
    n = len(a["id"])
    layout = carried_layout(n, sim.dtype, sim.state.extra)
    carried = ", ".join(k for k in layout if k.startswith(EXTRA_PREFIX)) or "none"
    for key, values in a.items():
        if not key.startswith(EXTRA_PREFIX):
            continue
        if key not in layout:
            raise CheckpointError(f"{ckpt.path}: {key!r}: this run carries no such array (the extra arrays it carries: "
                                  f"{carried})")
        shape, dtype = layout[key]
        if values.shape != shape or values.dtype != dtype:
            raise CheckpointError(f"{ckpt.path}: {key!r} is {values.dtype} {values.shape}, this run carries it as "
                                  f"{np.dtype(dtype).name} {shape}")
    nominal = float(sim.model.mass)
    lo, hi = nominal / MASS_FACTOR, nominal * MASS_FACTOR
    masses = a["m"]
    if n and not (lo <= float(masses.min()) and float(masses.max()) <= hi):
        bad = float(masses.min()) if float(masses.min()) < lo else float(masses.max())
        raise CheckpointError(f"{ckpt.path}: 'm' holds {bad:.6g} kg: its scene's particles have {nominal:.6g} kg "
                              f"(masses from {lo:.6g} to {hi:.6g} kg are accepted)")


def restore(sim, ckpt: Checkpoint):
    """Put the checkpoint's particles and step state into a freshly built Simulation of its scene."""
    a, m = ckpt.arrays, ckpt.manifest
    origin = [float(c) for c in m.get("origin", (0.0, 0.0, 0.0))]
    if origin != list(sim.scene.origin):  # its positions are relative to another point than this run's
        raise CheckpointError(f"{ckpt.path}: origin = {origin}: its positions are relative to that point, this "
                              f"version runs its scene relative to {list(sim.scene.origin)}")
    _check_fits_run(sim, ckpt)  # before anything of sim changes
    if sim.open.active:  # inlets and outlets: the particles at the checkpoint's time, not the scene's initial ones
        _restore_open(sim, ckpt)
    elif len(a["id"]) != sim.n_particles or not np.array_equal(a["id"], np.sort(sim.state.id)):
        raise CheckpointError(f"{ckpt.path}: its particles do not match its scene (the checkpoint holds "
                              f"{len(a['id'])} particles, the scene makes {sim.n_particles}"
                              f"{'' if len(a['id']) != sim.n_particles else ' with other ids'})")
    bodies = sim.model.walls.bodies
    saved = m.get("bodies", [])
    if len(saved) != len(bodies):
        raise CheckpointError(f"{ckpt.path}: bodies: the checkpoint holds {len(saved)} floating bodies, its scene has "
                              f"{len(bodies)}")
    for k, (body, values) in enumerate(zip(bodies, saved)):  # checked on a copy: nothing is half restored
        try:
            copy.deepcopy(body).set_state(values)
        except ValueError as e:
            raise CheckpointError(f"{ckpt.path}: bodies[{k}]: {e}") from None
    carried = {name: a[name] for name in CARRIED}
    for name, values in sim.state.extra.items():  # what this solver carries (zeros if the file lacks it)
        key = EXTRA_PREFIX + name
        carried[key] = a[key] if key in a else np.zeros_like(values[:0], shape=(len(a["id"]),) + values.shape[1:])
    sim.state = ParticleState.from_carried(carried, sim.dtype)
    # a skin's lists: sorted and built by the saved reference positions, as the continuous run had them
    sim.grid.from_reference = EXTRA_PREFIX + "x_ref" in a
    sim.step_index, sim.t, sim.dt, sim.dt_prev = int(m["step"]), float(m["t"]), float(m["dt"]), float(m["dt_prev"])
    sim.leaks, sim.max_neighbours = int(m["leaks"]), int(m["max_neighbours"])
    sim.max_compression, sim.last_limit = float(m["max_compression"]), m["last_limit"]
    sim.limit_counts.update({k: int(v) for k, v in m["limit_counts"].items()})
    for body, values in zip(bodies, saved):
        body.set_state(values)
    sim.model.walls.t = math.nan  # moved to the checkpoint's t (and bodies' state) before the next step
