"""Run health that the per-step checks (solver._choose_dt) cannot see: DFSPH solves that end
unconverged, and the mechanical energy of a closed scene that grows.

Both only read what the step computed; neither changes the physics. Their decisions come from
values every peer shares (the solves' global error sums; the energy as an integer sum over all
peers), so every peer warns or stops at the same step and N peers decide exactly as one process.

**Unconverged DFSPH solves.** A density or divergence solve that reaches ``sph.max_iterations``
with its mean error above its tolerance is an unconverged step. ``sph.on_unconverged = "stop"``
stops the run at the first one (SimulationError: exit code 3). ``"warn"`` (the default) logs it,
at the 1st, 10th, 100th ... unconverged step of each solve (a long run does not flood the log), and
stops once more than ``sph.max_unconverged_fraction`` of a solve's steps were unconverged, judged
from the ``MIN_SOLVED_STEPS``-th step on (one early unconverged step is not a trend).

**The energy watchdog.** A scene without moving walls (and without inlets) is closed and its body
forces are conservative, so its mechanical energy

    E = sum_i m_i (|v_i|^2 / 2 + u(x_i)),   u(x) = -(g + f_ext) . x + omega^2 |x - c|^2 / 2

can only fall (viscosity, wall friction and collisions dissipate it). Every
``run.energy_check_every`` steps E is compared with its value at the reference (the first step
after the body-force ramp, ``forces.ramp_time``); a growth beyond ``run.energy_growth`` times the
energy scale S warns (at each doubling of the growth) or, with ``run.on_energy_growth = "stop"``,
stops. S = the reference kinetic energy + sum_i m_i (u(x_i) - u_min), u_min the lowest potential in
the grid's box: the energy the fluid has to release (a dam break: m g times the height of its
centre of mass above the floor). The watchdog is off, and says why in summary.json, where E is not
the whole story: surface tension (surface energy), vorticity confinement (it adds energy by
design), a body force along a periodic axis or a central force on a periodic domain (no
potential), moving walls (they do work on the fluid), or no energy at all (at rest without body
forces). A change of the scene during the
run (``sph control set``) or a reset takes a new reference, and so does a resumed run (its first
step after the checkpoint).

Each particle's energy is rounded to an integer multiple of ENERGY_QUANTUM_BITS below the scene's
energy bound (its total mass times (|g + f_ext| L + omega^2 L^2 / 2 + c0^2 / 2), L the grid box's
diagonal), summed exactly in integers and over peers (``PeerHalo.reduce_sum``).
"""
from __future__ import annotations

import logging

import numpy as np

from sphcore.physics import energy
from sphcore.scene import artificial_alpha
from sphcore.stages import ENERGY

log = logging.getLogger("sph.health")

MIN_SOLVED_STEPS = 20        # the unconverged fraction is judged from this many solved steps on
ENERGY_QUANTUM_BITS = 40     # the energy sum resolves 2^-40 of the scene's energy bound
SOLVES = {"density": ("sph.density_tolerance", "mean |rho*/rho0 - 1|"),
          "divergence": ("sph.divergence_tolerance", "mean |D rho/Dt| dt / rho0")}


def _decade(count: int) -> bool:
    """True for 1, 10, 100, ...: the unconverged steps that are logged."""
    while count >= 10 and count % 10 == 0:
        count //= 10
    return count == 1


def _no_viscosity(scene) -> bool:
    """No dissipation in the momentum equation: no viscosity model, a zero coefficient."""
    sph = scene.sph
    return (sph.viscosity == "none" or (sph.viscosity == "artificial" and artificial_alpha(scene) == 0.0)
            or (sph.viscosity in ("muller", "morris") and sph.nu == 0.0))


def energy_cause(scene) -> str:
    """The likely cause of a closed scene gaining energy, and the remedy."""
    sph = scene.sph
    if _no_viscosity(scene):
        what = {"none": "sph.viscosity = 'none'", "artificial": "sph.alpha = 0"}.get(sph.viscosity,
                                                                                   f"sph.nu = 0 ({sph.viscosity})")
        return (f"likely cause: no viscosity ({what} and no physical viscosity): nothing removes the noise the "
                "particles pick up; set sph.alpha = 0.01-0.1 (artificial) or a physical viscosity "
                "(sph.viscosity = 'morris', sph.nu > 0)")
    if sph.solver == "dfsph":
        return ("likely cause: the pressure solves (tighten sph.density_tolerance, raise sph.max_iterations) or "
                "too long a step (lower time.cfl or time.dt)")
    return ("likely cause: too long a time step or too soft a fluid (lower time.cfl, raise sph.sound_speed), or "
            "too little viscosity (raise sph.alpha)")


class Health:
    """The health of one run (``Simulation.health``): what was warned about, what the energy did.
    Its settings are the scene's when the run starts (they are AT_START keys)."""

    def __init__(self, sim):
        self.sim = sim
        self.scene = scene = sim.scene
        self.on_unconverged = scene.sph.on_unconverged
        self.max_fraction = scene.sph.max_unconverged_fraction
        self.check_every = scene.run.energy_check_every
        self.growth_limit = scene.run.energy_growth
        self.on_growth = scene.run.on_energy_growth
        self.warnings = {"unconverged": 0, "energy": 0}  # warnings logged (rank 0) or due (other ranks)
        self.energy = {"watchdog": "on"}
        self._reference = None   # (scene, t) the reference was taken for
        self._last_t = 0.0       # the time of the previous step (a reset sets t back)
        self._warned_growth = 0.0

    # -- unconverged DFSPH solves --------------------------------------------------------------
    def solve_ended(self, halo, name: str, stats: dict, mean: float, tolerance: float):
        """After a recorded DFSPH solve (``stats`` updated): warn or stop if it ended unconverged."""
        if mean <= tolerance:
            return
        sim = self.sim
        sph = sim.scene.sph
        key, measure = SOLVES[name]
        count, steps = stats["unconverged"], stats["steps"]
        what = (f"the DFSPH {name} solve did not converge in sph.max_iterations = {sph.max_iterations} iterations: "
                f"{measure} = {mean:.3g} against {key} = {tolerance:g} ({count} of {steps} steps unconverged so "
                f"far)")
        remedy = (f"likely cause: too few iterations for this time step; raise sph.max_iterations, lower time.cfl "
                  f"or time.dt, or loosen {key}")
        if self.on_unconverged == "stop":
            sim._fail(f"{what} (sph.on_unconverged = 'stop'); {remedy}", rows="densest")
        if steps >= MIN_SOLVED_STEPS and count > self.max_fraction * steps:
            sim._fail(f"{what}: more than sph.max_unconverged_fraction = {self.max_fraction:g} of its steps; "
                      f"{remedy}", rows="densest")
        if _decade(count):
            self.warnings["unconverged"] += 1
            if getattr(halo, "rank", 0) == 0:
                log.warning("step %d (t = %.6g s): %s; %s (logged at the 1st, 10th, 100th ... unconverged step; "
                            "the run stops once more than sph.max_unconverged_fraction = %g of the steps are)",
                            sim.step_index, sim.t, what, remedy, self.max_fraction)

    # -- the energy watchdog -------------------------------------------------------------------
    def _off_reason(self, scene) -> str | None:
        """Why the energy watchdog cannot judge ``scene`` (None: it can)."""
        if self.check_every == 0 or self.growth_limit == 0.0:
            return "off (run.energy_check_every = 0 or run.energy_growth = 0)"
        if scene.terms.surface_tension > 0.0:
            return "off: terms.surface_tension > 0 (surface energy is not counted)"
        if scene.terms.vorticity_confinement > 0.0:
            return "off: terms.vorticity_confinement > 0 adds energy by design"
        if self.sim.model.walls.moves:
            return "off: moving walls do work on the fluid (the scene is not closed)"
        if scene.inlets or scene.outlets:
            return "off: inlets and outlets carry energy in and out (the scene is not closed)"
        body = np.add(scene.forces.gravity, scene.forces.external)
        periodic = scene.domain.periodic
        for axis in range(len(periodic)):
            if periodic[axis] and (body[axis] != 0.0 or scene.forces.central_omega > 0.0):
                return (f"off: a body force along the periodic axis {'xyz'[axis]} has no potential energy")
        return None

    def _energy_terms(self, scene) -> np.ndarray:
        """physics/energy.py's float64 constants: b = g + f_ext, u_min (the least -b . x in the grid's
        box: at its corner farthest along b), omega^2 / 2, the central force's centre, the unit, the clamp."""
        f = scene.forces
        body = np.add(f.gravity, f.external).astype(np.float64)
        grid = self.sim.model.host_grid
        lo = grid.origin.astype(np.float64)
        hi = lo + grid.ncell * grid.cell.astype(np.float64)
        terms = np.zeros(energy.TERMS, dtype=np.float64)
        terms[energy.BODY:energy.BODY + 3] = body
        terms[energy.U_MIN] = -float(np.sum(np.where(body > 0.0, body * hi, body * lo)))
        terms[energy.HALF_OMEGA2] = 0.5 * f.central_omega ** 2
        terms[energy.CENTRE:energy.CENTRE + 3] = f.central_center
        terms[energy.QUANTUM] = self._quantum(scene)
        terms[energy.CAP] = 2.0 ** 62 / max(self.sim.n_particles, 1)  # a blown-up run saturates, never overflows
        return terms

    def _quantum(self, scene) -> float:
        """The energy of one unit of the integer sum (J; J/m in 2D)."""
        sim = self.sim
        f = scene.forces
        grid = sim.model.host_grid
        L = float(np.linalg.norm(grid.ncell * grid.cell.astype(np.float64)))
        bound = (float(np.linalg.norm(np.add(f.gravity, f.external))) * L + 0.5 * f.central_omega ** 2 * L * L
                 + 0.5 * scene.sph.sound_speed ** 2)
        return sim.n_particles * sim.model.mass * bound * 2.0 ** -ENERGY_QUANTUM_BITS

    def _energy_sum(self, halo, scene, phase: str, kinetic_only: bool = False):
        """Generator: the energy over all peers, exactly (integer multiples of ``_quantum``): each row's
        units from the energy stage (physics/energy.py; on the device that holds the state), summed
        over peers."""
        sim = self.sim
        terms = self._energy_terms(scene)
        units = sim._run(ENERGY, energy_terms=terms, kinetic=bool(kinetic_only), dt_prev=sim.dtype.type(sim.dt_prev))
        total = yield from halo.reduce_sum(sim, phase, int(units))
        return total * terms[energy.QUANTUM]

    def after_step(self, halo):
        """Generator, after each step: every run.energy_check_every steps (and at the reference),
        the closed scene's mechanical energy against its reference."""
        sim = self.sim
        scene = sim.scene
        if self._reference is not None and (self._reference[0] is not scene or sim.t < self._last_t):
            self._reference = None  # the scene changed during the run, or a reset: a new reference
            self._warned_growth = 0.0
        self._last_t = sim.t
        off = self._off_reason(scene)
        if off is not None:
            self.energy = {"watchdog": off}
            return
        if self._reference is None:
            if sim.t < scene.forces.ramp_time:
                self.energy = {"watchdog": f"waiting for the end of forces.ramp_time = {scene.forces.ramp_time:g} s"}
                return
            total = yield from self._energy_sum(halo, scene, "energy")
            kinetic = yield from self._energy_sum(halo, scene, "energy_kinetic", kinetic_only=True)
            if total <= 0.0:
                self.energy = {"watchdog": "off: no energy to compare with (at rest, no body force)"}
                return
            self._reference = (scene, sim.t)
            self.energy = {"watchdog": "on", "reference_step": sim.step_index, "reference_t": sim.t,
                           "scale": total, "reference_kinetic": kinetic, "last": total, "last_step": sim.step_index,
                           "max_growth": 0.0}
            return
        if sim.step_index % self.check_every:
            return
        total = yield from self._energy_sum(halo, scene, "energy")
        record = self.energy
        growth = (total - record["scale"]) / record["scale"]
        record.update(last=total, last_step=sim.step_index, max_growth=max(record["max_growth"], growth))
        if growth <= self.growth_limit:
            return
        unit = "J/m" if scene.dim == 2 else "J"
        what = (f"the mechanical energy (kinetic + potential) of this closed scene grew by {100 * growth:.3g} % of "
                f"its scale {record['scale']:.4g} {unit} since t = {record['reference_t']:.4g} s (now "
                f"{total:.4g} {unit}), beyond run.energy_growth = {self.growth_limit:g}: the scheme is adding "
                f"energy; {energy_cause(scene)}")
        if self.on_growth == "stop":
            sim._fail(f"{what} (run.on_energy_growth = 'stop')", rows="fastest")
        if growth >= 2.0 * self._warned_growth:
            self._warned_growth = growth
            self.warnings["energy"] += 1
            if getattr(halo, "rank", 0) == 0:
                log.warning("step %d (t = %.6g s): %s (warned again when the growth doubles; "
                            "run.on_energy_growth = 'stop' stops the run)", sim.step_index, sim.t, what)

    def summary(self) -> dict:
        """summary.json's "health": warnings logged, the energy watchdog's state."""
        return {"warnings": dict(self.warnings), "energy": dict(self.energy),
                "on_unconverged": self.on_unconverged, "on_energy_growth": self.on_growth}
