"""Probes: pressure at a point and the free-surface height on a vertical line, sampled during a run.

A scene's ``[[probes]]`` (sphcore/scene.py ``Probe``) are measured every ``output.probes_every``
steps, after the step (``Simulation.stages`` calls ``Probes.after_step``), from the state the step
leaves: positions after its move, density and pressure of its density pass (the state a checkpoint,
the energy watchdog and the VTK files read). Rank 0 writes one row per sample to ``OUT/probes.csv``
(``ProbeWriter``) and the last values to summary.json; frames carry them to the viewer (Rerun
``probes/<name>``).

**Pressure at a point** (``kind = "pressure"``): the Shepard-normalised SPH interpolation
(Shepard 1968; Monaghan 2005, "Smoothed particle hydrodynamics", Rep. Prog. Phys. 68, eq. 2.4 with
the normalisation of sec. 2.4) over the particles j within the support radius H of the point x::

    phi(x) = sum_j V_j W(x - x_j),        V_j = m_j / rho_j            (the fluid fraction)
    p(x)   = sum_j V_j p_j W(x - x_j) / phi(x)

Normalising by phi makes a constant pressure exact wherever the support is partly empty (at a
wall, near the free surface); a linear field is exact where the particles are symmetric about x and
first-order accurate elsewhere: at a wall the value is the pressure at the centroid of the fluid in
the support, a fraction of H inside the fluid (tests/test_probes.py measures both). **Dry rule**: a
point with phi(x) < ``threshold`` (default ``DRY_FRACTION`` = 0.05) reads 0 Pa, the gauge pressure
of the air: a wall transducer in air reads atmospheric pressure, and a number (not NaN) keeps peak
and impulse sums over time well defined. 0.05 lies well below the phi of a wetted wall (about 0.5)
or corner (0.25 in 2D, 0.125 in 3D), so only a point without fluid within its support, or with a
few spray particles at its edge, counts as dry.

**Free-surface height** (``kind = "height"``): the vertical is opposite gravity, e = -g / |g|
(the scene's gravity when the run starts). phi is sampled on the line x(s) = at + s e at every
quarter spacing inside the domain's bounding box; the surface is the highest point where
phi >= ``threshold`` (default ``SURFACE_FRACTION`` = 0.5), linearly interpolated between that
sample and the next one up. This is the wave-gauge method of DualSPHysics (GaugeSwl: the highest
point of the gauge where the kernel-interpolated mass reaches half the reference mass, i.e.
phi = 0.5; its developers advise 0.4 in 2D,
https://forums.dual.sphysics.org/discussion/1930/regarding-free-surface-elevation-post-processing-in-dualsphysics).
The value is the surface's coordinate along e (m; y in a scene whose gravity points along -y), not
a depth above the floor. A line without any sample reaching the threshold is dry: NaN (there is no
surface to place), written as ``nan`` in probes.csv and ``null`` in summary.json.

That highest point jumps to any spray or sheet of water that crosses the line above the water (in a
3D dam break, to over 1 m where the water is 0.3 m deep: docs/VALIDATION.md, the MARIN case). With
``gauge = "wire"`` the surface is instead the line's lowest sample plus the line's wetted length, the
stretches where phi >= threshold (phi linear between samples; ``wetted_length``), which is what a
resistance or capacitance wire gauge reads: its signal grows with the immersed length of the wire
(Hughes 1993, "Physical Models and Laboratory Techniques in Coastal Engineering"), so a
drop on the wire adds its own thickness, not its height. Where the water is one column standing on
the floor, both gauges read the same surface (to the interpolation at the floor, where phi is about
the threshold); a bubble or a gap between the floor and the water reads lower with the wire.

**Across peers, bitwise.** Each peer sums its owned rows only. Every particle's contribution is
rounded to an integer number of quanta (``FRACTION_QUANTUM`` of phi, ``pressure_quantum`` of
V p W), so the partial sums are int64 and their sum over peers (``PeerHalo.reduce_sums``) is exact
and independent of the order: N peers write the same probes.csv as one process, to the last bit.
The per-particle arithmetic is plain numpy in float64, elementwise (no reductions whose order could
depend on the array), so a particle contributes the same bits whichever peer owns it.

The reduction is tagged with the step that has just run (``sim.step_index - 1``), phase
``"probes"`` (unique within a step: the step's own messages are positions, fields, reduce, ...). A
tag of the next step, as the energy watchdog uses, would move a Zenoh peer's mailbox on to that step
before a pause that follows this step, and turn a replay of this step from a duplicate into an old
step (tests/test_hostile.py); with this step's tag the probes change nothing in what a peer accepts.
For the same reason the probes reduce before the energy watchdog: once a peer has waited for a
message of the next step, one of this step is an old step to it and would be dropped.
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from sphcore.checkpoint import CheckpointError
from sphcore.choices import KERNELS, Kernel
from sphcore.initial import check_probes_inside, outside_domain
from sphcore.physics.kernels import kernel_constants
from sphcore.scene import pressure_scale

DRY_FRACTION = 0.05          # pressure: phi below this reads 0 Pa (dry)
SURFACE_FRACTION = 0.5       # height: the surface is the highest point with phi >= this
SAMPLES_PER_SPACING = 4      # height: samples of phi per particle spacing along the line
FRACTION_QUANTUM = 2.0 ** -40  # one unit of the integer sums of phi
PRESSURE_QUANTUM_BITS = 40   # V p W resolves 2^-40 of the scene's pressure scale
UNITS = {"pressure": "Pa", "height": "m"}
PHASE = "probes"


def kernel_values(kernel: Kernel, r: np.ndarray, H: float, s_w: float) -> np.ndarray:
    """W(r) of the density kernel ``kernel`` (physics/kernels.py ``w``, same formulas) for an
    array of distances, in float64; 0 at r >= H."""
    r = np.asarray(r, dtype=np.float64)
    inside = r < H
    if kernel == Kernel.MULLER:
        d = H * H - r * r
        value = s_w * d * d * d
    elif kernel == Kernel.CUBIC_SPLINE:
        q = 2.0 * r / H
        t = 2.0 - q
        value = np.where(q < 1.0, s_w * (1.0 - 1.5 * q * q + 0.75 * q * q * q), 0.25 * s_w * t * t * t)
    else:
        q = r / H
        t = 1.0 - q
        t2 = t * t
        value = s_w * t2 * t2 * (1.0 + 4.0 * q)
    return np.where(inside, value, 0.0)


def wetted_length(s: np.ndarray, phi: np.ndarray, threshold: float) -> float:
    """The length (m) of a height probe's line where phi >= threshold, phi linear between neighbouring
    samples (offsets ``s``, ascending). A gap in the line (its samples inside an obstacle are left out)
    adds nothing."""
    ds = np.diff(s)
    step = ds.min() if ds.size else 0.0
    a, b = phi[:-1] - threshold, phi[1:] - threshold
    both = (a >= 0.0) & (b >= 0.0)
    one = (a >= 0.0) != (b >= 0.0)
    part = np.where(one, np.maximum(a, b) / np.where(one, np.abs(a - b), 1.0), 0.0)  # the wet side of a crossing
    joined = ds <= 1.5 * step
    return float(np.sum(np.where(joined, ds * np.where(both, 1.0, part), 0.0)))


def vertical(scene) -> np.ndarray:
    """The unit vector opposite the scene's gravity (the zero vector without gravity)."""
    g = np.array(scene.forces.gravity, dtype=np.float64)
    norm = math.sqrt(float(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]))
    return -g / norm if norm > 0.0 else np.zeros(3)


class Probes:
    """The probes of one run (``Simulation.probes``), fixed when the run starts. ``last``: the most
    recent sample, (step, t, values) with one float per probe in scene order, or None;
    ``samples``: every sample not yet taken by the viewer's frames (``take_samples``)."""

    def __init__(self, sim):
        self.sim = sim
        scene = sim.scene
        self.items = scene.probes
        self.names = [p.name for p in self.items]
        self.kinds = [p.kind for p in self.items]
        self.last = None
        self.samples = []
        if not self.items:
            return
        model = sim.model
        check_probes_inside(scene, model.walls)
        self.kernel = KERNELS[scene.sph.kernel]
        self.H = float(model.H)
        self.s_w = kernel_constants(self.kernel, scene.dim, self.H)[0]
        grid = model.host_grid
        self.period = np.where(np.asarray(grid.period, dtype=np.float64) > 0.0,
                               np.asarray(grid.period, dtype=np.float64), 0.0)
        self.points = [np.array(p.at, dtype=np.float64) for p in self.items]
        self.origin = scene.origin  # the points are relative to it; a height is reported in world coordinates
        self.e = vertical(scene)
        self.thresholds = [p.threshold or (DRY_FRACTION if p.kind == "pressure" else SURFACE_FRACTION)
                           for p in self.items]
        self.gauges = [p.gauge for p in self.items]
        self.lines = [self._line(scene, model.walls, p.at) if p.kind == "height" else None for p in self.items]
        self.sizes = [2 if p.kind == "pressure" else len(line) for p, line in zip(self.items, self.lines)]
        L = float(np.linalg.norm(grid.ncell * grid.cell.astype(np.float64)))  # the grid's diagonal
        self.pressure_quantum = pressure_scale(scene, L) * 2.0 ** -PRESSURE_QUANTUM_BITS
        self.cap = 2.0 ** 62 / max(sim.n_particles, 1)  # a blown-up run saturates instead of overflowing

    def _line(self, scene, walls, at) -> np.ndarray:
        """The offsets s (m, ascending) of a height probe's samples at + s e inside the domain's
        bounding box and inside the domain."""
        at = np.array(at, dtype=np.float64)
        lo, hi = walls.lo.astype(np.float64), walls.hi.astype(np.float64)
        s_lo, s_hi = -math.inf, math.inf
        for d in range(scene.dim):
            if abs(self.e[d]) > 1e-12:
                a, b = (lo[d] - at[d]) / self.e[d], (hi[d] - at[d]) / self.e[d]
                s_lo, s_hi = max(s_lo, min(a, b)), min(s_hi, max(a, b))
        ds = scene.particles.spacing / SAMPLES_PER_SPACING
        s = s_lo + ds * np.arange(int(math.floor((s_hi - s_lo) / ds + 1e-9)) + 1)
        inside = ~outside_domain(walls, scene, at + s[:, None] * self.e, scene.particles.spacing)
        return s[inside]

    # -- the measurement -----------------------------------------------------------------------
    def _relative(self, x: np.ndarray, point: np.ndarray) -> np.ndarray:
        """x - point, by the minimum image on periodic axes (elementwise, float64)."""
        rel = x - point
        for d in range(3):
            L = self.period[d]
            if L > 0.0:
                rel[:, d] = rel[:, d] - L * np.floor(rel[:, d] / L + 0.5)
        return rel

    def _units(self, values: np.ndarray, quantum: float) -> np.ndarray:
        return np.rint(np.clip(values / quantum, -self.cap, self.cap)).astype(np.int64)

    def partial_sums(self, x, m, rho, p) -> np.ndarray:
        """The integer partial sums of rows (x, m, rho, p) (a peer's owned rows): per pressure probe
        [phi, V p W] in units of FRACTION_QUANTUM and pressure_quantum, per height probe phi at each
        sample of its line."""
        x = np.asarray(x, dtype=np.float64)
        V = np.asarray(m, dtype=np.float64) / np.asarray(rho, dtype=np.float64)
        p = np.asarray(p, dtype=np.float64)
        H2 = self.H * self.H
        out = []
        for point, kind, line in zip(self.points, self.kinds, self.lines):
            rel = self._relative(x, point)
            if kind == "pressure":
                r2 = rel[:, 0] * rel[:, 0] + rel[:, 1] * rel[:, 1] + rel[:, 2] * rel[:, 2]
                near = np.nonzero(r2 < H2)[0]
                w = kernel_values(self.kernel, np.sqrt(r2[near]), self.H, self.s_w)
                fraction = V[near] * w
                out.append(np.array([self._units(fraction, FRACTION_QUANTUM).sum(),
                                     self._units(fraction * p[near], self.pressure_quantum).sum()], dtype=np.int64))
                continue
            e = self.e
            along = rel[:, 0] * e[0] + rel[:, 1] * e[1] + rel[:, 2] * e[2]
            r2 = rel[:, 0] * rel[:, 0] + rel[:, 1] * rel[:, 1] + rel[:, 2] * rel[:, 2]
            near = np.nonzero(r2 - along * along < 1.01 * H2)[0]  # within H of the line (W cuts exactly)
            # each particle meets only the samples within H of it along the line
            first = np.searchsorted(line, along[near] - self.H, "left")
            count = np.searchsorted(line, along[near] + self.H, "right") - first
            pair = np.repeat(np.arange(len(near)), count)
            sample = np.repeat(first - np.cumsum(count) + count, count) + np.arange(int(count.sum()))
            j = near[pair]
            d = rel[j] - line[sample][:, None] * e[None, :]
            w = kernel_values(self.kernel, np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]),
                              self.H, self.s_w)
            units = np.zeros(len(line), dtype=np.int64)
            np.add.at(units, sample, self._units(V[j] * w, FRACTION_QUANTUM))  # integers: exact in any order
            out.append(units)
        return np.concatenate(out) if out else np.zeros(0, dtype=np.int64)

    def values(self, sums: np.ndarray) -> np.ndarray:
        """Each probe's value (Pa or m; NaN for a dry height line) from the global sums."""
        values = []
        at = 0
        for point, kind, line, size, threshold, gauge in zip(self.points, self.kinds, self.lines, self.sizes,
                                                             self.thresholds, self.gauges):
            part = sums[at: at + size]
            at += size
            if kind == "pressure":
                phi = float(part[0]) * FRACTION_QUANTUM
                values.append(float(part[1]) * self.pressure_quantum / phi if phi >= threshold else 0.0)
                continue
            phi = part.astype(np.float64) * FRACTION_QUANTUM
            wet = np.nonzero(phi >= threshold)[0]
            if not len(wet):
                values.append(math.nan)
                continue
            if gauge == "wire":
                s = float(line[0]) + wetted_length(line, phi, threshold)
            else:
                k = int(wet[-1])
                s = float(line[k])
                if k + 1 < len(line):  # the crossing between sample k (wet) and k + 1 (below the threshold)
                    s += float(line[k + 1] - line[k]) * (phi[k] - threshold) / (phi[k] - phi[k + 1])
            base = float(sum((point[d] + self.origin[d]) * self.e[d] for d in range(3)))  # a world height
            values.append(base + s)
        return np.array(values, dtype=np.float64)

    def measure(self, halo, step: int):
        """Generator: every probe's value now, over all peers (``step`` tags the reduction)."""
        sim = self.sim
        s = sim.state
        n = s.n_owned
        mine = self.partial_sums(s.x[:n], s.m[:n], s.rho[:n], s.p[:n])
        sums = yield from halo.reduce_sums(sim, PHASE, mine, step)
        return self.values(np.asarray(sums, dtype=np.int64))

    def due(self) -> bool:
        every = self.sim.scene.output.probes_every  # a live key: every peer changes it after the same step
        return bool(self.items) and every > 0 and self.sim.step_index % every == 0

    def after_step(self, halo):
        """Generator, after each step: every output.probes_every steps, sample every probe."""
        if not self.due():
            return
        sim = self.sim
        with sim.timers("probes"):
            values = yield from self.measure(halo, sim.step_index - 1)
        self.last = (sim.step_index, sim.t, values)
        self.samples.append(self.last)
        del self.samples[:-MAX_PENDING_SAMPLES]

    def take_samples(self) -> list:
        """The samples since the last call (the viewer's frames carry them), oldest first."""
        out, self.samples = self.samples, []
        return out

    def summary(self) -> dict | None:
        """summary.json's "probes": period, units, file, and the last sample (None for NaN)."""
        if not self.items:
            return None
        record = {"every": self.sim.scene.output.probes_every, "file": "probes.csv",
                  "units": {n: UNITS[k] for n, k in zip(self.names, self.kinds)}, "last": None}
        if self.last is not None:
            step, t, values = self.last
            record["last"] = {"step": step, "t": t,
                              **{n: (float(v) if math.isfinite(v) else None) for n, v in zip(self.names, values)}}
        return record


MAX_PENDING_SAMPLES = 1000  # samples kept for the viewer's next frame (one process without frames drops older ones)


class ProbeWriter:
    """OUT/probes.csv, written by rank 0: a header ``step,t,<name>...`` (units: Pa for pressure, m for
    height; docs/USAGE.md), then one row per sample, appended and flushed as the run goes.

    A run that starts at step k > 0 (resumed from a checkpoint, or restarted after a lost peer)
    keeps the rows of steps <= k of an existing probes.csv with the same header and drops the later
    ones, which the run is about to write again: no row is doubled or lost. A run from step 0, or a
    file with other columns, starts the file afresh; a file that is not text stops the run before
    its first step (CheckpointError)."""

    def __init__(self, path: Path, probes: Probes, start_step: int):
        self.path = Path(path)
        self.probes = probes
        self.header = ",".join(["step", "t", *probes.names])
        kept = []
        if start_step > 0 and self.path.is_file():
            lines = self._existing_lines(start_step)
            if lines and lines[0] == self.header:
                for line in lines[1:]:
                    step = line.split(",", 1)[0]
                    if step.isdigit() and int(step) <= start_step:
                        kept.append(line)
        tmp = self.path.with_name(f".{self.path.name}.tmp")
        tmp.write_text("\n".join([self.header, *kept]) + "\n")
        os.replace(tmp, self.path)
        self.file = open(self.path, "a")
        self.written = None  # the step of the last row written

    def _existing_lines(self, start_step: int) -> list[str]:
        """The lines of the probes.csv a continued run finds. One with other columns is another
        scene's and is started afresh; one that is not UTF-8 text is no probes.csv at all (some other
        file under that name) and is refused rather than overwritten. CheckpointError, the type the
        CLI reports as bad input: only a run continuing a checkpoint (start_step > 0) reads it."""
        try:
            data = self.path.read_bytes()
        except OSError as e:
            raise CheckpointError(f"{self.path}: unreadable ({e.strerror or e}); a run resumed at step "
                                  f"{start_step} keeps its rows up to that step") from None
        try:
            return data.decode("utf-8").splitlines()
        except UnicodeDecodeError as e:
            raise CheckpointError(f"{self.path}: not a probes.csv (byte 0x{data[e.start]:02x} at offset {e.start} is "
                                  f"not UTF-8 text); a run resumed at step {start_step} keeps the rows up to that step "
                                  "of the probes.csv it wrote: move the file away or choose another --out") from None

    def after_step(self):
        """Append the newest sample if it is of this step and not written yet."""
        last = self.probes.last
        if last is None or last[0] != self.probes.sim.step_index or last[0] == self.written:
            return
        step, t, values = last
        self.file.write(",".join([str(step), repr(float(t)), *(repr(float(v)) for v in values)]) + "\n")
        self.file.flush()
        self.written = step

    def close(self):
        self.file.close()
