"""The stages of a time step, each declared once.

A stage is one pass over the owned rows: ``row(*choices, ..., i, ...)`` computes and writes row i
(gather, never scatter). Its declaration names the row function, the arrays it writes and how the
rows' return values combine; everything else is read from the row function's own parameter names:

- parameters named in ``CHOICES`` are compile-time choices (they come first): each scene compiles
  only the branches it uses;
- ``i`` is the row;
- every other parameter names an argument of ``ARGUMENTS`` (an array of the state, the scratch, the
  grid or the walls, or a scalar the step passes).

From the declarations the backends generate all the plumbing: the CPU ``prange`` driver
(``backends/cpu.py``), the CUDA kernel with its launch and block reductions (``backends/cuda.py``),
the PTX type signatures of ``cuda.compile_all``, and the per-row scratch arrays (``SCRATCH``). The
step (``solver.Simulation.stages``) then runs a stage as ``engine.run(FORCES, prm=prm)``.

Adding an optional term: its physics file (pair function + row function), one ``Stage`` here and
its scene key; docs/ARCHITECTURE.md walks through an example.
"""
from __future__ import annotations

import inspect
from dataclasses import dataclass
from functools import cached_property
from types import MappingProxyType

from sphcore.choices import EOS, Integrator, Kernel, PressureGradient, Viscosity
from sphcore.grid import CELL_WALK, NEIGHBOUR_LISTS
from sphcore.physics.balsara import balsara_row
from sphcore.physics.damping import damping_row
from sphcore.physics.continuity import density_update_row, diffusion_row
from sphcore.physics.density import density_row
from sphcore.physics.dfsph import (dfsph_factor_row, dfsph_finish_row, dfsph_kick_row, dfsph_source_row, dfsph_update_row,
                                   dfsph_warm_ghost_row)
from sphcore.physics.drag import drag_row
from sphcore.physics.energy import energy_row
from sphcore.physics.bodies import body_reaction_row
from sphcore.physics.integration import boundaries_row, integrate_row, statistics_row
from sphcore.physics.momentum import acceleration_row
from sphcore.physics.open_boundary import open_boundary_row, outlet_pressure_row
from sphcore.physics.shifting import shifting_row
from sphcore.physics.surface_tension import surface_tension_row
from sphcore.physics.vorticity import confinement_row, vorticity_row
from sphcore.physics.wall_friction import wall_friction_row
from sphcore.physics.xsph import xsph_row

# Compile-time choices: name -> (the values a scene can select, the default the PTX check starts from,
# what it selects). Drivers receive them as integers (numba literals / CUDA closure constants).
CHOICES = MappingProxyType({
    "kernel": (tuple(int(k) for k in Kernel), int(Kernel.WENDLAND_C2), "smoothing kernel family (choices.Kernel)"),
    "eos": (tuple(int(e) for e in EOS), int(EOS.TAIT), "equation of state (choices.EOS)"),
    "viscosity": (tuple(int(v) for v in Viscosity), int(Viscosity.ARTIFICIAL), "viscosity model (choices.Viscosity)"),
    "viscosity_switch": ((0, 1), 0, "1: Balsara's switch scales each pair's artificial viscosity by (f_i + f_j) / 2 "
                                    "(physics/balsara.py, sph.viscosity_switch)"),
    "pressure_gradient": (tuple(int(g) for g in PressureGradient), int(PressureGradient.SYMMETRIC),
                          "the forces pass's pressure gradient (choices.PressureGradient, physics/pressure.py)"),
    "integrator": (tuple(int(g) for g in Integrator), int(Integrator.SYMPLECTIC_EULER), "time integrator"),
    "periodic": ((0, 1), 0, "1 if any axis is periodic: minimum-image separations and wrapping"),
    "neighbours": ((NEIGHBOUR_LISTS, CELL_WALK), NEIGHBOUR_LISTS,
                   "how a neighbour pass finds j: the stored lists, or a walk of the grid cells around i (grid.py)"),
    "pair_gradients": ((0, 1), 0, "DFSPH: 1 if the density pass stores m_j grad W_ij per list entry (grad_w) and "
                                  "the DFSPH passes read it (lists on the CPU: pairs.mass_gradient)"),
    "continuity": ((0, 1), 0, "1 if the density is carried by the continuity equation (sph.density)"),
    "divergence": ((0, 1), 0, "DFSPH: 1 for the divergence solve on v, 0 for the density solve on v*"),
    "add": ((0, 1), 0, "shifting: 1 adds to dv (XSPH wrote it), 0 writes it"),
    "use_drift": ((0, 1), 0, "1 if the drift uses v + dv (XSPH or shifting on)"),
})

# Every argument a row function may name: name -> (type, meaning and unit). Types: "params" (the
# Params NamedTuple), "float" (a scalar in the run's precision), "int", "bool", "vec" (n, 3) and "row" (n,)
# arrays in the run's precision, "nbr" (n, capacity) int32 neighbour lists (column-major on the
# GPU), "pairs" (3, n, capacity) in the run's precision (a value per list entry), "counts" (n,) int32, "cells" (grid.Cells), "cell_rows" (cells,) int64, "cell_flags" (cells,) uint8, "kinds" (walls,)
# int32, "table" 2-D float arrays, "terms64" a (k,) float64 array whatever the precision.
ARGUMENTS = MappingProxyType({
    "prm": ("params", "physical parameters (params.Params)"),
    # the particle state (state.ParticleState); kappa and rho_c are carried arrays (state.extra)
    "x": ("vec", "position (m)"),
    "v": ("vec", "velocity (m/s); or v* where a stage runs on it (DFSPH density solve)"),
    "a": ("vec", "acceleration (m/s^2)"),
    "m": ("row", "mass (kg)"),
    "rho": ("row", "density (kg/m^3)"),
    "p": ("row", "pressure (Pa)"),
    "kappa": ("row", "DFSPH kappa = p / rho^2, the density solve's warm start (carried)"),
    "rho_c": ("row", "the carried density of sph.density = 'continuity' (kg/m^3; carried)"),
    # the grid (grid.Grid / cuda.DeviceGrid)
    "nbr": ("nbr", "neighbour lists: row k holds i's neighbour rows j"),
    "counts": ("counts", "neighbour list lengths"),
    "grad_w": ("pairs", "m_j grad W_ij of i's k-th list entry, [c, i, k] (kg/m^4 in 3D; with pair_gradients: "
                        "the density pass writes it)"),
    "cells": ("cells", "the grid's geometry for the cell walk (grid.Cells)"),
    "cell_begin": ("cell_rows", "first row of every cell (rows sorted by cell, id)"),
    "cell_end": ("cell_rows", "one past the last row of every cell"),
    # the walls (boundaries.build_walls)
    "wall_kind": ("kinds", "wall primitive kinds (choices.WallKind)"),
    "wall_data": ("table", "wall primitive geometry rows (physics/walls.py)"),
    "wall_tables": ("table", "tabulated wall integrals (boundaries.py)"),
    "wall_motion": ("table", "each wall's velocity [0:3] (m/s), acceleration [3:6] (m/s^2), angular velocity [6:9] "
                             "(rad/s) and acceleration [9:12] (rad/s^2) about its pivot [12:15] (m), now (motion.py)"),
    "wall_zones": ("table", "inlet and outlet zones: [kind, lo (3), hi (3), U (3)] (physics/open_boundary.py)"),
    "wall_damping": ("table", "damping zones: [lo (3), hi (3), start, 1 / (end - start), axis, rate] "
                              "(physics/damping.py)"),
    "wall_near": ("cell_flags", "1 for every grid cell a wall may reach within H (boundaries.near_wall_cells): "
                                "only its particles evaluate the walls' terms (physics/walls.near_wall)"),
    "lo": ("row", "the grid origin (3,) (m): periodic wrapping"),
    # per-step scalars the step passes
    "dt": ("float", "this step (s)"),
    "dt_prev": ("float", "the previous step (s)"),
    "inv_dt": ("float", "1 / dt (1/s)"),
    "share": ("float", "DFSPH: the share of the density error this step removes"),
    "rho_ref": ("float", "DFSPH: the density solve's target density (kg/m^3)"),
    "rho0": ("float", "rest density (kg/m^3)"),
    "commit": ("bool", "continuity: store the advanced carried density"),
    "store": ("bool", "DFSPH: store the solved kappa and p"),
    "coefficient": ("float", "a force term's scene value (Stage.key), in the run's precision"),
    "wall": ("int", "a floating body's wall row (physics/bodies.py)"),
    "quantum": ("float", "a floating body's force unit (N; N/m in 2D): the exact sum's integer step"),
    "torque_quantum": ("float", "a floating body's torque unit (N m; N in 2D): quantum x its reach"),
    "energy_terms": ("terms64", "the energy watchdog's float64 constants: body force, u_min, central force, the "
                                "integer unit, the clamp (physics/energy.py)"),
    "kinetic": ("bool", "energy: the kinetic part only"),
})


@dataclass(frozen=True)
class Scratch:
    """A per-row work array of the step, owned by the backend; (n,) or (n, 3) rows for the n rows of
    the state (owned + ghosts) when ``needed`` by the model, one row otherwise."""

    name: str
    components: int   # 1: (n,), 3: (n, 3)
    needed: str       # the Simulation flag that needs it ("" = always)
    initial: float    # its value when (re)allocated
    meaning: str


SCRATCH = (
    Scratch("fill", 1, "", 1.0, "wall fill fraction theta of the density stage (physics/walls.py)"),
    Scratch("dv", 3, "use_drift", 0.0, "drift correction dv (m/s): XSPH and shifting (x += dt (v + dv))"),
    Scratch("balsara", 1, "use_balsara", 1.0, "Balsara's switch f_i of the artificial viscosity (physics/balsara.py)"),
    Scratch("omega", 3, "use_vorticity", 0.0, "vorticity (1/s; physics/vorticity.py)"),
    Scratch("drho", 1, "continuity", 0.0, "delta-SPH density diffusion D rho / Dt (kg/m^3/s; continuity.py)"),
    Scratch("wgrad", 3, "dfsph", 0.0, "DFSPH wall gradient g^wall (kg/m^4; physics/dfsph.py)"),
    Scratch("inv_d", 1, "dfsph", 0.0, "DFSPH 1 / D_i (m^8/kg^2 in 3D)"),
    Scratch("lam", 1, "dfsph", 0.0, "DFSPH lambda_i = kappa_i dt^2 of this iteration (m^3/kg in 3D)"),
    Scratch("lam_sum", 1, "dfsph", 0.0, "DFSPH sum of lambda_i over the solve"),
    Scratch("v_star", 3, "dfsph", 0.0, "DFSPH predicted velocity v* (m/s)"),
)
SCRATCH_NAMES = frozenset(s.name for s in SCRATCH)

# How a stage's row values combine; each gives the same result in any order. name -> (the value's
# type, the operation). The integer kinds share one int64 result buffer, "max" has a float64 one.
REDUCTIONS = MappingProxyType({
    "sum": ("int64", "+"),     # integer sum (exact)
    "imax": ("int64", "max"),  # integer maximum (a count >= 0)
    "max": ("float64", "max"),  # maximum of a real value >= 0 (the step statistics)
})
MAX_REDUCED = 6  # values of one type a stage may reduce (the backends' result buffers)


def reduction_slots(reduce: tuple) -> list[tuple[str, int]]:
    """(value type, index in that type's result buffer) of each reduced value of a stage."""
    types = [REDUCTIONS[kind][0] for kind in reduce]
    return [(t, types[:k].count(t)) for k, t in enumerate(types)]


@dataclass(frozen=True)
class Stage:
    """One pass over the owned rows: ``row`` writes ``writes`` of row i; ``reduce`` combines the
    rows' return values (one entry per returned value), or () if the row returns nothing. A force
    term (``FORCE_TERMS``) names the scene ``key`` ("section.name") that switches it on when > 0; its
    row receives that value as ``coefficient`` if it takes one."""

    name: str
    row: object
    writes: tuple
    reduce: tuple = ()
    key: str = ""

    # read once from the row function (every stage call binds by them: inspect is slow)
    @cached_property
    def parameters(self) -> tuple:
        return tuple(inspect.signature(self.row.py_func).parameters)

    @cached_property
    def choices(self) -> tuple:
        """The compile-time choices, in the row's order."""
        return tuple(p for p in self.parameters if p in CHOICES)

    @cached_property
    def arguments(self) -> tuple:
        """The row's arguments after the choices, without i."""
        return tuple(p for p in self.parameters if p not in CHOICES and p != "i")

    @property
    def reads(self) -> tuple:
        return tuple(a for a in self.arguments if a not in self.writes)

    @property
    def neighbour_pass(self) -> bool:
        """Walks the neighbour lists: compiled with the reassociation licences (cpu.FASTMATH)."""
        return "nbr" in self.arguments

    def check(self):
        """The declaration agrees with its row function (run at import: a typo fails at once)."""
        params = self.parameters
        n = len(self.choices)
        if params[:n] != self.choices:
            raise TypeError(f"stage {self.name}: choices {self.choices} must come first in {self.row.__name__}")
        if "i" not in params:
            raise TypeError(f"stage {self.name}: {self.row.__name__} has no row parameter i")
        for a in self.arguments:
            if a not in ARGUMENTS and a not in SCRATCH_NAMES:
                raise TypeError(f"stage {self.name}: {self.row.__name__} names {a!r}, which is neither an "
                                "argument (stages.ARGUMENTS) nor a scratch array (stages.SCRATCH)")
        for a in self.writes:
            if a not in self.arguments:
                raise TypeError(f"stage {self.name}: writes {a!r}, which {self.row.__name__} does not take")
        for r in self.reduce:
            if r not in REDUCTIONS:
                raise TypeError(f"stage {self.name}: reduction {r!r} is not one of {tuple(REDUCTIONS)}")
        if any(slot >= MAX_REDUCED for _, slot in reduction_slots(self.reduce)):
            raise TypeError(f"stage {self.name}: more than {MAX_REDUCED} reduced values of one type")
        if self.key and self.key.count(".") != 1:
            raise TypeError(f"stage {self.name}: key {self.key!r} must be 'section.name' of a scene key")
        return self


# -- the stages, in the order a step may run them (solver.Simulation.stages orders them) ------------
DENSITY = Stage("density", density_row, writes=("rho_c", "rho", "p", "fill", "grad_w"),
                reduce=("sum", "imax")).check()  # returns i's neighbour count: their sum and maximum
DFSPH_FACTOR = Stage("dfsph_factor", dfsph_factor_row, writes=("p", "wgrad", "inv_d", "lam_sum"),
                     reduce=("sum",)).check()  # returns rho_i / rho0 - 1 quantised: the mean density
BALSARA = Stage("balsara", balsara_row, writes=("balsara",)).check()
FORCES = Stage("forces", acceleration_row, writes=("a",)).check()
DIFFUSION = Stage("diffusion", diffusion_row, writes=("drho",)).check()
SURFACE_TENSION = Stage("surface_tension", surface_tension_row, writes=("a",),
                        key="terms.surface_tension").check()
DRAG = Stage("drag", drag_row, writes=("a",), key="terms.drag").check()
WALL_FRICTION = Stage("wall_friction", wall_friction_row, writes=("a",), key="terms.wall_friction").check()
VORTICITY = Stage("vorticity", vorticity_row, writes=("omega",)).check()
CONFINEMENT = Stage("confinement", confinement_row, writes=("a",)).check()
DAMPING = Stage("damping", damping_row, writes=("a",)).check()
XSPH = Stage("xsph", xsph_row, writes=("dv",)).check()
SHIFTING = Stage("shifting", shifting_row, writes=("dv",)).check()
OPEN_BOUNDARY = Stage("open_boundary", open_boundary_row, writes=("v", "a", "dv")).check()
OUTLET_PRESSURE = Stage("outlet_pressure", outlet_pressure_row, writes=("rho", "p")).check()
STATISTICS = Stage("statistics", statistics_row, writes=(),
                   reduce=("max", "max", "max", "sum")).check()  # max |v|^2, |a|^2, compression; bad rows
DFSPH_KICK = Stage("dfsph_kick", dfsph_kick_row, writes=("v_star", "lam", "lam_sum")).check()
DFSPH_WARM_GHOSTS = Stage("dfsph_warm_ghosts", dfsph_warm_ghost_row, writes=("lam",)).check()  # on the ghost rows
DFSPH_SOURCE = Stage("dfsph_source", dfsph_source_row, writes=("lam_sum", "lam"),
                     reduce=("sum",)).check()  # returns the quantised density error
DFSPH_UPDATE = Stage("dfsph_update", dfsph_update_row, writes=("v", "lam_sum")).check()
DFSPH_FINISH = Stage("dfsph_finish", dfsph_finish_row, writes=("a", "p", "kappa")).check()
DENSITY_UPDATE = Stage("density_update", density_update_row, writes=("rho_c",)).check()
INTEGRATE = Stage("integrate", integrate_row, writes=("x", "v")).check()
BOUNDARIES = Stage("boundaries", boundaries_row, writes=("x", "v"), reduce=("sum",)).check()  # leaks
BODY_REACTION = Stage("body_reaction", body_reaction_row, writes=(),
                      reduce=("sum",) * 6).check()  # F, T about the body's centre
ENERGY = Stage("energy", energy_row, writes=(), reduce=("sum",)).check()  # the energy watchdog's integer units

# Force terms: each adds to a after FORCES, in this order, when its scene key is > 0
FORCE_TERMS = (SURFACE_TENSION, DRAG, WALL_FRICTION)


def overlap_group(*group: Stage) -> tuple:
    """Stages a peer may run on its interior rows while a halo phase is on its way and on the other
    rows after it arrived (solver.Simulation._overlapped): checked here to give the same bits as one
    pass over all rows. Each stage alone does (a row reads no other row of an array its stage
    writes: gather), and so does the group when no stage reads an array that an earlier one writes
    (it would read a neighbour's value that is not written yet); a stage that adds to an array it
    writes (a force term: a += ...) touches only its own row."""
    written = set()
    for stage in group:
        early = written.intersection(stage.reads)
        if early:
            raise TypeError(f"stage {stage.name} reads {sorted(early)}, written by an earlier stage of its overlap "
                            "group: split into interior and boundary rows it would read values not yet written")
        written.update(stage.writes)
    return group


# What runs while exchange 2 (the ghosts' rho, p) travels: the accelerations the scene enables, in order
ACCELERATIONS = overlap_group(FORCES, DIFFUSION, *FORCE_TERMS)

STAGES = (DENSITY, OUTLET_PRESSURE, DFSPH_FACTOR, BALSARA, FORCES, DIFFUSION, *FORCE_TERMS, VORTICITY, CONFINEMENT, DAMPING, XSPH, SHIFTING,
          OPEN_BOUNDARY, STATISTICS, DFSPH_KICK, DFSPH_WARM_GHOSTS, DFSPH_SOURCE, DFSPH_UPDATE, DFSPH_FINISH, DENSITY_UPDATE, INTEGRATE, BOUNDARIES,
          BODY_REACTION, ENERGY)


def covering_choices(stage: Stage) -> list[dict]:
    """The choice combinations the PTX check compiles for ``stage``: the defaults (a scene's default
    path), then rounds that move every choice to its other values at once, so that every value of
    every choice is compiled in at least one kernel. The branches of different choices are
    independent of each other (each is its own ``if`` on one choice), so this covers every branch with
    1 + max(values - 1) kernels per stage instead of the product of the choices' values."""
    default = {c: CHOICES[c][1] for c in stage.choices}
    others = {c: [v for v in CHOICES[c][0] if v != default[c]] for c in stage.choices}
    rounds = max((len(o) for o in others.values()), default=0)
    combos = [default]
    for r in range(rounds):
        combos.append({c: others[c][r % len(others[c])] if others[c] else default[c] for c in stage.choices})
    return combos
