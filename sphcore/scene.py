"""Scenes: TOML files parsed into frozen, validated dataclasses.

Every key of every section is declared here once, with its type, default, allowed range or choices
and a one-line help. Loading checks unknown keys, types, ranges and combinations, and raises
``SceneError`` naming the key, the value and what is allowed. ``--set section.key=value`` overrides
are applied to the raw TOML data before validation, so they pass through the same checks.
"""
from __future__ import annotations

import dataclasses
import difflib
import json
import math
import os
import re
import tomllib
import unicodedata
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sphcore.choices import EOSES, INTEGRATORS, KERNELS, PRESSURE_GRADIENTS, VISCOSITIES
from sphcore.mesh_sdf import MeshCheckError, check_mesh_obstacle, read_mesh


class SceneError(ValueError):
    """A scene (or an override) is invalid; the message names the key, the value and what is allowed."""


def spec(default, help: str, *, range: tuple | None = None, choices=None, min_exclusive: bool = False,
         length: tuple | None = None, control: bool | str | None = None, rows: int | None = None,
         position: bool = False):
    """Declare a scene key: default, help text and constraints (checked by ``_check_value``),
    ``control``: LIVE if the key may change while the run goes on, else why not (None: the reason
    of its section, ``SECTION_CONTROL``), and ``position``: a point in world coordinates, which the
    run holds relative to the scene's origin (``localised``)."""
    meta = {"help": help, "range": range, "choices": choices, "min_exclusive": min_exclusive, "length": length,
            "control": control, "rows": rows, "position": position}
    if isinstance(default, list):  # arrays of tables are held as tuples, exactly as _build stores them
        return field(default=tuple(default), metadata=meta)
    if isinstance(default, dict):
        return field(default_factory=lambda: dict(default), metadata=meta)
    return field(default=default, metadata=meta)


VEC = (2, 3)  # vectors may have 2 (2D scenes) or 3 components

# Which keys may change while a run goes on (``sph control OUT set KEY=VALUE``, and ``sph run --resume
# DIR --set KEY=VALUE``): LIVE ones, applied by every peer after the same step, rebuild only the
# Params and the scene the step reads, or switch optional stages on or off (sphcore/solver.py
# ``Simulation.change_scene`` checks that nothing else changed). Every other key names why not.
LIVE = True
COMPILED = "changes the compiled step (a kernel, a stage choice or which stages run)"
PARTICLES = "changes the particle set or the initial particles (spacing, blocks, initial flow)"
WORLD = "changes the walls or the grid (container, planes, obstacles, support radius)"
AT_LOAD = "is checked once, when the scene is loaded"
AT_START = "is read once, when the run starts"
RUN_LENGTH = "fixes the run's length when it starts (--steps / --until)"
PEERS = "fixes the peers' blocks when the peers start (balancing moves the cuts between them)"
VIEWER = ("is read by the viewer when it starts; switch the view with the commands camera NAME and "
          "color_by QUANTITY")
OUTPUT = "fixes what the VTK series holds when the run starts"
PROBES = "fixes the columns of probes.csv when the run starts"


@dataclass(frozen=True)
class SceneInfo:
    name: str = spec("scene", "short name, used in logs and output metadata")
    description: str = spec("", "one-line description")
    dim: int = spec(3, "spatial dimension", choices=(2, 3), control=PARTICLES)


@dataclass(frozen=True)
class Particles:
    spacing: float = spec(0.02, "initial lattice spacing dx in m: the one resolution key", range=(0.0, math.inf),
                          min_exclusive=True, control=PARTICLES)
    max_particles: int = spec(20_000_000, "refuse scenes that would create more particles than this",
                              range=(1, 10**10), control=AT_LOAD)


@dataclass(frozen=True)
class Block:
    shape: str = spec("box", "shape of the fluid region", choices=("box", "sphere"))
    min: tuple = spec((0.0, 0.0, 0.0), "box: lower corner (m)", length=VEC, position=True)
    max: tuple = spec((0.0, 0.0, 0.0), "box: upper corner (m)", length=VEC, position=True)
    center: tuple = spec((0.0, 0.0, 0.0), "sphere: centre (m)", length=VEC, position=True)
    radius: float = spec(0.0, "sphere: radius (m)", range=(0.0, math.inf))
    velocity: tuple = spec((0.0, 0.0, 0.0), "initial velocity (m/s)", length=VEC)
    frame: str = spec("world", "coordinates of min/max/center: world or the container's local frame",
                      choices=("world", "container"))
    clip: bool = spec(False, "keep only the part of the block inside the domain (false: a block reaching outside "
                             "the container or a plane is an error naming how many particles fall outside)")
    lattice: str = spec("cartesian", "how the block is filled: cartesian (a square / cubic lattice of the spacing) or "
                        "polar (a sphere block only: rings about its centre in 2D, spherical shells in 3D, one "
                        "spacing apart, each with as many points as its circumference / area holds; it fits "
                        "circular walls about the same centre, which a cartesian lattice meets with gaps)",
                        choices=("cartesian", "polar"))


@dataclass(frozen=True)
class Fluid:
    rest_density: float = spec(1000.0, "rest density rho0 (kg/m^3; 1e-3 to 1e6: rho^2 and p / rho^2 stay within "
                               "float32's range)", range=(1e-3, 1e6),
                               control=LIVE)
    initial_flow: str = spec("none", "analytic initial velocity field added to the blocks' velocity; straining: "
                             "u = A (x - c), v = -A (y - c) (the oscillating drop)",
                             choices=("none", "taylor_green", "straining"), control=PARTICLES)
    flow_speed: float = spec(1.0, "taylor_green: velocity amplitude U (m/s)", range=(0.0, math.inf), control=PARTICLES)
    flow_rate: float = spec(0.0, "straining: the strain rate A (1/s)", range=(-math.inf, math.inf), control=PARTICLES)
    flow_center: tuple = spec((0.0, 0.0, 0.0), "straining: the centre c of the flow (m)", length=VEC, control=PARTICLES,
                              position=True)
    blocks: list = spec([], "regions filled with fluid on a lattice of the given spacing ([[fluid.blocks]])",
                        control=PARTICLES)


@dataclass(frozen=True)
class SPH:
    solver: str = spec("wcsph", "pressure solver: wcsph (weakly compressible, pressure from the EOS) or dfsph "
                       "(incompressible, Bender & Koschier 2017: pressure solved every step; eos and sound_speed "
                       "unused)", choices=("wcsph", "dfsph"), control=COMPILED)
    density_tolerance: float = spec(0.001, "dfsph: the density solve iterates until the mean |rho*/rho0 - 1| is "
                                    "below this", range=(0.0, 1.0), min_exclusive=True, control=LIVE)
    divergence_tolerance: float = spec(0.001, "dfsph: the divergence solve iterates until the mean |D rho/Dt| dt / "
                                       "rho0 is below this (0 = no divergence solve)", range=(0.0, 1.0), control=LIVE)
    max_iterations: int = spec(100, "dfsph: most iterations of either solve in one step", range=(1, 10_000),
                               control=LIVE)
    on_unconverged: str = spec("warn", "dfsph: a solve that ends at max_iterations above its tolerance: warn (logged "
                               "at the 1st, 10th, 100th ... such step; the run stops once more than "
                               "max_unconverged_fraction of the steps are) or stop (at the first, exit code 3)",
                               choices=("warn", "stop"), control=AT_START)
    max_unconverged_fraction: float = spec(0.5, "dfsph, on_unconverged = warn: stop (exit code 3) once more than this "
                                           "fraction of a solve's steps ended unconverged, judged from its 20th "
                                           "step on (1 = never stop)", range=(0.0, 1.0), control=AT_START)
    density: str = spec("summation", "density: summation (rho = sum m W, from the positions) or continuity "
                        "(integrated D rho/Dt with delta-SPH diffusion: smooth pressure at rest; wcsph only)",
                        choices=("summation", "continuity"), control=COMPILED)
    delta: float = spec(0.1, "continuity: delta-SPH diffusion coefficient delta (Molteni & Colagrossi 2009, with "
                        "the hydrostatic correction of Fourtakas et al. 2019; 0 = no diffusion)", range=(0.0, 1.0),
                        control=LIVE)
    kernel: str = spec("wendland_c2", "smoothing kernel family", choices=tuple(KERNELS), control=COMPILED)
    support: float = spec(2.3, "support radius H in units of the spacing (about 50 neighbours in 3D at 2.3; from "
                          "1.5: at 1 no lattice neighbour is within H and the kernel's moments are 0)",
                          range=(1.5, 4.0), control=WORLD)
    eos: str = spec("tait", "equation of state", choices=tuple(EOSES), control=COMPILED)
    sound_speed: float = spec(20.0, "numerical speed of sound c0 (m/s); >= 10x the largest flow speed",
                              range=(0.0, math.inf), min_exclusive=True, control=LIVE)
    clamp_negative_pressure: bool = spec(True, "floor pressure at 0 (free surfaces); false for closed flows",
                                         control=LIVE)
    background_pressure: float = spec(0.0, "p_b in Pa added to every particle's EOS pressure (Morris, Fox & Zhu "
                                      "1997): keeps a confined flow's pressure positive, so that no void opens "
                                      "where it would be negative (a lid-driven cavity's corner); wcsph, closed "
                                      "flows only (clamp_negative_pressure = false, no inlets or outlets); 0 = off",
                                      range=(0.0, 1.0e9), control=LIVE)
    pressure_gradient: str = spec("symmetric", "wcsph: the momentum equation's pressure gradient. symmetric "
                                  "(Monaghan 1992; conserves momentum) or difference: (p_j - p_i) in the bulk, "
                                  "which a uniform pressure does not enter, and the symmetric form in the free "
                                  "surface's layer; for slow viscous flow around bodies under a hydrostatic head "
                                  "(physics/pressure.py), with terms.shifting > 0",
                                  choices=tuple(PRESSURE_GRADIENTS), control=COMPILED)
    body_force: str = spec("reaction", "how the fluid's force and torque on a floating body are measured: reaction "
                           "(to the walls' push on the particles, physics/bodies.py; conserves momentum) or traction "
                           "(the surface integral of -p n + mu (grad u + grad u^T) n, p and grad u fitted from the "
                           "particles at points on the surface, physics/traction.py; exact for a uniform pressure "
                           "whatever the particles' arrangement; needs and is needed by pressure_gradient = difference)",
                           choices=("reaction", "traction"), control=WORLD)
    viscosity: str = spec("artificial", "viscosity model", choices=tuple(VISCOSITIES), control=COMPILED)
    alpha: float = spec(0.02, "artificial viscosity coefficient (viscosity = artificial)", range=(0.0, 10.0),
                        control=LIVE)
    alpha_nu: float = spec(0.0, "the artificial viscosity given as the shear viscosity it acts with, nu = alpha c0 "
                           "h / (2 (dim + 2)) in m^2/s (Monaghan 2005; h = half the support radius), in place of "
                           "alpha, which then follows the spacing so that the model's viscosity does not (a resolution "
                           "study converges to one model; docs/VALIDATION.md, the dam break); 0 = use alpha",
                           range=(0.0, 1.0e3), control=LIVE)
    viscosity_switch: str = spec("none", "balsara: each pair's artificial viscosity scaled by Balsara's switch "
                                 "(f_i + f_j) / 2, f = |div v| / (|div v| + |curl v| + 1e-4 c0 / h): kept where the "
                                 "flow compresses, taken out where it shears (Balsara 1995; physics/balsara.py); "
                                 "one more neighbour pass a step; viscosity = artificial only",
                                 choices=("none", "balsara"), control=COMPILED)
    nu: float = spec(1.0e-6, "kinematic viscosity (m^2/s) (viscosity = muller or morris)", range=(0.0, 1.0e3),
                     control=LIVE)


@dataclass(frozen=True)
class Terms:
    xsph: float = spec(0.0, "XSPH velocity smoothing eps (0 = off; typical 0.1-0.5)", range=(0.0, 1.0), control=LIVE)
    shifting: float = spec(0.0, "Fickian particle shifting coefficient A, D = A h |v| dt (0 = off; typical 1-2 with "
                                     "a free surface; 8 in the closed Taylor-Green and cavity scenes, where it also "
                                     "refills voids; walls count as fluid)",
                           range=(0.0, 10.0), control=LIVE)
    surface_tension: float = spec(0.0, "colour-field surface tension sigma in N/m (0 = off)", range=(0.0, 1.0e3),
                                  control=LIVE)
    surface_threshold: float = spec(0.1, "colour-gradient threshold as a fraction of 1/spacing", range=(0.0, 10.0),
                                    control=LIVE)
    vorticity_confinement: float = spec(0.0, "vorticity confinement eps in m/s (0 = off)", range=(0.0, 1.0e3),
                                        control=LIVE)
    drag: float = spec(0.0, "linear drag k in 1/s, a += -k v: damps a flow to rest, e.g. to settle a tank before "
                       "a run (0 = off; keep k dt < 1)", range=(0.0, 1.0e4), control=LIVE)
    wall_friction: float = spec(0.0, "turbulent wall friction: the kinematic viscosity nu (m^2/s) of a smooth-wall "
                                "law (Spalding's) that sets every wall's shear stress from the slip of the "
                                "particles next to it (water 1e-6; 0 = off, free-slip or Morris walls as they are)",
                                range=(0.0, 1.0e3), control=LIVE)


@dataclass(frozen=True)
class Forces:
    gravity: tuple = spec((0.0, -9.81, 0.0), "gravitational acceleration (m/s^2)", length=VEC, control=LIVE)
    external: tuple = spec((0.0, 0.0, 0.0), "constant external acceleration, any direction (m/s^2)", length=VEC,
                           control=LIVE)
    hydrostatic: str = spec("resolved", "resolved: gravity acts on the fluid, whose pressure carries its weight; "
                            "removed: the fluid moves under its modified pressure p - rho0 g . x (no gravity on it) "
                            "and each floating body feels its weight less its buoyancy, (1 - rho0 / rho_body) g. "
                            "The same flow for a closed, full container (no free surface), without the "
                            "hydrostatic pressure level's error in the pressure gradient (docs/VALIDATION.md, "
                            "the settling cylinder); pressures (probes) are then p - rho0 g . x",
                            choices=("resolved", "removed"), control=AT_START)
    ramp_time: float = spec(0.0, "gravity and external force rise smoothly from 0 over this time (s); 0 = at once",
                            range=(0.0, 1.0e6), control=LIVE)
    central_omega: float = spec(0.0, "central force field a = -omega^2 (x - central_center) (1/s; 0 = off), e.g. "
                                "the oscillating drop of Monaghan & Rafiee 2013", range=(0.0, 1.0e6), control=LIVE)
    central_center: tuple = spec((0.0, 0.0, 0.0), "centre of the central force field (m)", length=VEC, control=LIVE,
                                  position=True)


@dataclass(frozen=True)
class Time:
    integrator: str = spec("symplectic_euler", "time integrator", choices=tuple(INTEGRATORS), control=COMPILED)
    mode: str = spec("adaptive", "time step: fixed dt, or adaptive from CFL limits", choices=("fixed", "adaptive"),
                     control=LIVE)
    dt: float = spec(1.0e-4, "fixed: the time step; adaptive: the largest allowed step (s)",
                     range=(0.0, 1.0), min_exclusive=True, control=LIVE)
    cfl: float = spec(0.25, "CFL number for the acoustic, force, viscous and shifting limits", range=(0.0, 2.0),
                      min_exclusive=True, control=LIVE)
    steps: int = spec(200, "steps to run when neither --steps nor --until is given", range=(0, 10**9),
                      control=RUN_LENGTH)


def _motion(what: str) -> dict:
    """The keys of a wall's prescribed translation (sphcore/motion.py), declared once for every kind
    of wall that can move: X(t) = velocity t + amplitude (sin(2 pi frequency t + phase) - sin(phase))."""
    return {
        "velocity": spec((0.0, 0.0, 0.0), f"the {what}'s constant velocity (m/s; along a plane: a sliding wall that "
                                          "drags the fluid)", length=VEC),
        "amplitude": spec((0.0, 0.0, 0.0), f"the {what}'s oscillation amplitude (m)", length=VEC),
        "frequency": spec(0.0, "oscillation frequency (Hz; 0 = none)", range=(0.0, math.inf)),
        "phase": spec(0.0, "oscillation phase at t = 0 (degrees)", range=(-360.0, 360.0)),
        "angular_velocity": spec((0.0, 0.0, 0.0), f"the {what}'s constant rotation rate about its pivot (degrees/s, a "
                                                  "vector along the axis; 2D: z only)", length=VEC),
        "angular_amplitude": spec((0.0, 0.0, 0.0), f"the {what}'s oscillation of its angle about its pivot (degrees, a "
                                                   "vector along the axis, at frequency and phase; parallel to "
                                                   "angular_velocity)", length=VEC),
        "pivot": spec((0.0, 0.0, 0.0), f"the point the {what} turns about, from its "
                                       f"{'point' if what == 'plane' else 'centre'} at t = 0 (m)", length=VEC),
        "path": spec((), f"instead: a table of the {what}'s displacement from where the scene puts it, rows [t, x, y(, z)] "
                         "(s, m), t increasing, the first row's displacement 0; a monotone cubic between rows, at "
                         "rest before the first and after the last", rows=MAX_PATH_ROWS),
    }


MAX_PATH_ROWS = 100_000  # rows of a wall's path table
_PLANE_MOTION, _OBSTACLE_MOTION = _motion("plane"), _motion("obstacle")


@dataclass(frozen=True)
class Plane:
    point: tuple = spec((0.0, 0.0, 0.0), "a point on the plane at t = 0 (m)", length=VEC, position=True)
    normal: tuple = spec((0.0, 1.0, 0.0), "normal pointing into the fluid", length=VEC)
    velocity: tuple = _PLANE_MOTION["velocity"]
    amplitude: tuple = _PLANE_MOTION["amplitude"]
    frequency: float = _PLANE_MOTION["frequency"]
    phase: float = _PLANE_MOTION["phase"]
    angular_velocity: tuple = _PLANE_MOTION["angular_velocity"]
    angular_amplitude: tuple = _PLANE_MOTION["angular_amplitude"]
    pivot: tuple = _PLANE_MOTION["pivot"]
    path: tuple = _PLANE_MOTION["path"]


@dataclass(frozen=True)
class Domain:
    container: str = spec("box", "container shape (none: only planes / periodic axes bound the fluid)",
                          choices=("box", "sphere", "cylinder", "none"))
    center: tuple = spec((0.0, 0.0, 0.0), "container centre (m)", length=VEC, position=True)
    size: tuple = spec((1.0, 1.0, 1.0), "box: edge lengths; cylinder: (diameter, height, -) (m)", length=VEC)
    radius: float = spec(0.5, "sphere: radius (m)", range=(0.0, math.inf), min_exclusive=True)
    rotation: tuple = spec((0.0, 0.0, 0.0), "container rotation about x, y, z (degrees, applied x then y then z)",
                           length=VEC)
    scale: float = spec(1.0, "uniform scale of the container about its centre", range=(0.0, math.inf),
                        min_exclusive=True)
    periodic: tuple = spec((False, False, False), "periodic axes (box container, no rotation)", length=VEC)
    bounds_min: tuple = spec((0.0, 0.0, 0.0), "container = none: lower corner of the simulated region (m)",
                             length=VEC, position=True)
    bounds_max: tuple = spec((0.0, 0.0, 0.0), "container = none: upper corner of the simulated region (m)",
                             length=VEC, position=True)
    planes: list = spec([], "extra planar walls ([[domain.planes]])")


@dataclass(frozen=True)
class Obstacle:
    shape: str = spec("sphere", "obstacle shape", choices=("sphere", "box", "mesh"))
    center: tuple = spec((0.0, 0.0, 0.0), "centre (m)", length=VEC, position=True)
    file: str = spec("", "mesh: triangle mesh (STL, OBJ, PLY), relative to the scene file; centred on its bounds")
    scale: float = spec(1.0, "mesh: uniform scale", range=(0.0, math.inf), min_exclusive=True)
    radius: float = spec(0.1, "sphere: radius (m)", range=(0.0, math.inf), min_exclusive=True)
    size: tuple = spec((0.1, 0.1, 0.1), "box: edge lengths (m)", length=VEC)
    rotation: tuple = spec((0.0, 0.0, 0.0), "box and mesh: rotation about x, y, z (degrees)", length=VEC)
    frame: str = spec("world", "coordinates of center: world or the container's local frame",
                      choices=("world", "container"))
    velocity: tuple = _OBSTACLE_MOTION["velocity"]
    amplitude: tuple = _OBSTACLE_MOTION["amplitude"]
    frequency: float = _OBSTACLE_MOTION["frequency"]
    phase: float = _OBSTACLE_MOTION["phase"]
    angular_velocity: tuple = _OBSTACLE_MOTION["angular_velocity"]
    angular_amplitude: tuple = _OBSTACLE_MOTION["angular_amplitude"]
    pivot: tuple = _OBSTACLE_MOTION["pivot"]
    path: tuple = _OBSTACLE_MOTION["path"]
    density: float = spec(0.0, "a floating body: its density (kg/m^3), moved by the fluid's force and the body "
                               "forces (sphere and box; 0 = fixed, or moved as velocity/amplitude say)",
                          range=(0.0, math.inf))
    free: tuple = spec((True, True, True), "a floating body: the axes it may move along", length=VEC)
    free_rotation: tuple = spec((False, False, False), "a floating body: the axes x, y, z it may turn about, through "
                                "its centre (2D: z only, [false, false, true]); none: it keeps its orientation",
                                length=(3,))


@dataclass(frozen=True)
class Boundary:
    restitution: float = spec(0.0, "normal velocity kept (reversed) on wall contact", range=(0.0, 1.0), control=LIVE)
    friction: float = spec(0.0, "fraction of tangential velocity removed on wall contact", range=(0.0, 1.0),
                           control=LIVE)
    gap: float = spec(0.25, "closest approach to a wall, in units of the spacing", range=(0.0, 0.5), control=LIVE)


@dataclass(frozen=True)
class Run:
    precision: str = spec("auto", "floating point precision; auto = f64 on the CPU, f32 on a GPU (--precision "
                                  "overrides)", choices=("auto", "f32", "f64"), control=COMPILED)
    neighbours: str = spec("lists", "how the neighbour passes find neighbours: lists (built once per step, "
                                    "~256 B per particle; faster on the CPU) or walk (each pass walks the "
                                    "grid cells around the particle; no per-particle lists). Same neighbours, "
                                    "in the same order on the same grid (run.cells_per_support)",
                           choices=("lists", "walk"), control=COMPILED)
    cells_per_support: int = spec(0, "grid cells per support radius along each axis: 2 (cells of H/2) halves the "
                                     "candidates a neighbour search tests, for 8x the cells (32 B each); 1 (cells "
                                     "of H); 0 = by run.neighbours: 2 with lists (built once a step), 1 with the "
                                     "walk (whose every pass would visit 125 cells instead of 27). Same neighbours; "
                                     "the order of the sums, so the rounding, differs between 1 and 2",
                                  choices=(0, 1, 2), control=AT_START)
    neighbour_skin: float = spec(-1.0, "Verlet lists: build the lists out to H (1 + skin) and reuse them, filtered to H, "
                                       "until some particle has moved 0.45 skin H (0 = build every step; -1 = auto: "
                                       "with lists on the CPU backend 0.2 for WCSPH and 0.45 for DFSPH, whose steps "
                                       "move particles farther; else 0). The same neighbours each step, summed "
                                       "in the order of the last build: the last bits differ from a skin of 0; N "
                                       "peers and a resumed run keep one process's bits (docs/BENCHMARKS.md)",
                                 range=(-1.0, 1.0), control=AT_START)
    log_every: int = spec(0, "steps between progress log lines when not on a terminal (0 = every 5 % of the run)",
                          range=(0, 10**9), control=AT_START)
    max_density_ratio: float = spec(3.0, "stop with a diagnostic if some rho/rho0 exceeds this",
                                    range=(1.0, math.inf), min_exclusive=True, control=LIVE)
    energy_check_every: int = spec(100, "energy watchdog: steps between checks of a closed scene's mechanical energy "
                                        "(kinetic + potential in the body forces; 0 = off)", range=(0, 10**9),
                                   control=AT_START)
    energy_growth: float = spec(0.25, "energy watchdog: act when the mechanical energy grows by more than this "
                                "fraction of its scale (the energy the fluid can release: kinetic + potential "
                                "above the lowest point) since the start (0 = off)", range=(0.0, math.inf),
                                control=AT_START)
    on_energy_growth: str = spec("warn", "energy watchdog: warn (again at each doubling of the growth) or stop "
                                 "(exit code 3) when the growth exceeds energy_growth", choices=("warn", "stop"),
                                 control=AT_START)


@dataclass(frozen=True)
class DecompositionSection:
    layout: str = spec("auto", "how peers split the domain: auto (gravity's axis uncut where possible, then the least work "
                       "for the busiest peer: its particles and its share of the halo) or slabs (along "
                       "the longest axis)",
                       choices=("auto", "slabs"))
    dims: tuple = spec((0, 0, 0), "peers per axis (px, py, pz); all 0 = chosen from the peer count and layout",
                       length=(3,))
    balance_every: int = spec(0, "move the cut planes every this many steps so peers get near-equal work "
                                 "(0 = fixed cuts; the first cuts always balance the initial particles)",
                              range=(0, 10**9), control=LIVE)
    balance_by: str = spec("time", "what balancing equalises: measured compute time (particles weighted by each "
                                   "peer's seconds per particle) or particle counts (reproducible cuts)",
                           choices=("time", "particles"), control=LIVE)
    overlap: bool = spec(True, "peers compute the rows out of every ghost's reach while a halo exchange travels, "
                               "the others after it (the same bits either way); false: wait for each exchange first",
                         control=AT_START)


@dataclass(frozen=True)
class RenderCamera:
    name: str = spec("camera", "name used to switch to this camera (render.camera, the control channel)")
    eye: tuple = spec((1.0, 1.0, 2.0), "camera position (m)", length=(3,), position=True)
    target: tuple = spec((0.0, 0.0, 0.0), "point looked at (m)", length=(3,), position=True)
    up: tuple = spec((0.0, 1.0, 0.0), "up direction", length=(3,))
    fov: float = spec(40.0, "vertical field of view (degrees)", range=(1.0, 170.0))


# render.surface = "auto" turns the live surface on up to this many particles; its cost grows with the
# particles (the colour field) and the surface's area (the mesh), docs/BENCHMARKS.md "Live surface"
SURFACE_AUTO_MAX = 300_000
SURFACE_NODES = 50_000  # render.surface_step = 0: about this many lattice nodes inside the fluid


@dataclass(frozen=True)
class Render:
    every: int = spec(10, "steps between rendered frames (each peer renders its own particles; 0 = no frames)",
                      range=(0, 10**9))
    width: int = spec(640, "image width (pixels)", range=(16, 8192))
    height: int = spec(480, "image height (pixels)", range=(16, 8192))
    color_by: str = spec("speed", "quantity shown by colour", choices=("speed", "density", "pressure", "rank"))
    range: tuple = spec((0.0, 0.0), "colour range [low, high]; [0, 0] = a default for the quantity "
                                     "(speed 0..c0/10, density rho0 +-2 %, pressure 0..0.02 rho0 c0^2)", length=(2,))
    radius: float = spec(0.6, "splat radius in spacings", range=(0.05, 10.0))
    camera: str = spec("default", "active camera: 'default' (frames the domain) or a [[render.cameras]] name")
    points_every: int = spec(0, "log every k-th particle (by id) as a 3D point cloud (0 = about 3000 points in all)",
                             range=(0, 10**9))
    surface: str = spec("auto", "live fluid surface (the colour field's 0.5 level, a mesh in 3D, lines in 2D) beside "
                                f"the point cloud; auto: on up to {SURFACE_AUTO_MAX:,} particles (docs/BENCHMARKS.md: "
                                "its cost per frame)", choices=("auto", "on", "off"))
    surface_every: int = spec(10, "frames between live surface meshes (each adds ~0.4 MB to the recording at most: "
                                  "the mesh's size is bounded, render.surface_step)", range=(1, 10**6))
    surface_step: float = spec(0.0, "live surface sampling grid step, in particle spacings (0 = 1 spacing, coarser "
                                     f"above {SURFACE_NODES:,} particles so the mesh stays the same size)",
                               range=(0.0, 4.0))
    cameras: list = spec([], "extra named cameras ([[render.cameras]])")


@dataclass(frozen=True)
class Output:
    checkpoint_every: int = spec(0, "write a checkpoint every this many steps (0 = none; --checkpoint-every)",
                                 range=(0, 10**9), control=LIVE)
    checkpoint_keep: int = spec(2, "how many of the newest checkpoints to keep", range=(1, 10**6), control=LIVE)
    vtk_every: int = spec(0, "write ParaView files (.vtp particles, .pvd series) every this many steps "
                             "(0 = none; --vtk K)", range=(0, 10**9), control=LIVE)
    surface: bool = spec(False, "with vtk_every: also extract the fluid surface (marching cubes) per frame")
    surface_resolution: float = spec(0.5, "surface sampling grid step, in particle spacings", range=(0.1, 4.0))
    probes_every: int = spec(10, "steps between samples of the [[probes]] into probes.csv (0 = none; 1 to catch "
                                 "impact peaks)", range=(0, 10**9), control=LIVE)


PROBE_KINDS = ("pressure", "height")
PROBE_GAUGES = ("highest", "wire")  # a height probe's surface: sphcore/probes.py
PROBE_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_.-]{0,63}")  # a CSV column and a Rerun entity path part as it is


@dataclass(frozen=True)
class Probe:
    name: str = spec("", "probes.csv column and Rerun entity probes/<name>: a letter, then letters, digits, _ . - "
                         "(at most 64; unique)")
    kind: str = spec("pressure", "pressure: p (Pa) interpolated at the point at (Shepard); height: the free surface "
                                 "(m, along the vertical, against gravity) on the vertical line through at",
                     choices=PROBE_KINDS)
    at: tuple = spec((0.0, 0.0, 0.0), "pressure: the point; height: a point of the vertical line (m, inside the "
                                      "domain; required)", length=VEC, position=True)
    threshold: float = spec(0.0, "fluid fraction sum_j (m_j/rho_j) W: pressure: dry (reads 0 Pa) below it; height: "
                                 "the surface is where it falls below it (0 = the kind's default: 0.05 for pressure, "
                                 "0.5 for height)", range=(0.0, 1.0), min_exclusive=False)
    gauge: str = spec("highest", "height: highest: the highest point of the line where the fraction reaches "
                                 "threshold (spray above the water counts); wire: the line's lowest point plus "
                                 "its wetted length, as a wire gauge reads (spray adds its thickness, not its "
                                 "height)", choices=PROBE_GAUGES)


OPEN = "creates or removes particles where the run's particle bookkeeping fixes it when the run starts"


@dataclass(frozen=True)
class Inlet:
    min: tuple = spec((0.0, 0.0, 0.0), "the inlet zone, a box: lower corner (m); it fills itself with a lattice of "
                                       "the spacing that moves at velocity", length=VEC, position=True)
    max: tuple = spec((0.0, 0.0, 0.0), "the inlet zone: upper corner (m); at least the support radius thick along "
                                       "velocity", length=VEC, position=True)
    velocity: tuple = spec((0.0, 0.0, 0.0), "the inflow velocity (m/s), along one axis: particles in the zone move "
                                            "at it, new layers enter at its back face and become fluid past its "
                                            "front face", length=VEC)


@dataclass(frozen=True)
class Outlet:
    min: tuple = spec((0.0, 0.0, 0.0), "the outlet zone, a box: lower corner (m); particles in it move on with the "
                                       "velocity they came with", length=VEC, position=True)
    max: tuple = spec((0.0, 0.0, 0.0), "the outlet zone: upper corner (m); at least the support radius thick along "
                                       "direction", length=VEC, position=True)
    direction: tuple = spec((1.0, 0.0, 0.0), "the outward axis (a unit vector along x, y or z): particles past the "
                                             "zone's face along it are removed", length=VEC)
    pressure: float = spec(0.0, "the pressure in the zone (Pa, gauge: the EOS's p = 0 at rest density); the flow "
                                "leaves against it", range=(-math.inf, math.inf))


@dataclass(frozen=True)
class DampingZone:
    min: tuple = spec((0.0, 0.0, 0.0), "the zone, a box: lower corner (m); particles in it are slowed by a_i -= k v_i",
                      length=VEC, position=True)
    max: tuple = spec((0.0, 0.0, 0.0), "the zone: upper corner (m)", length=VEC, position=True)
    direction: tuple = spec((1.0, 0.0, 0.0), "a unit vector along x, y or z: k grows along it, from 0 at the face the "
                                             "waves enter by to rate at the far face (k = rate s^2)", length=VEC)
    rate: float = spec(0.0, "k at the zone's far face (1/s; > 0): rate x time.dt must stay below 1, and a wave "
                            "of angular frequency omega is spent over a zone a wavelength long at rate of a few omega",
                       range=(0.0, 1e9), min_exclusive=True)


SECTIONS: dict[str, type] = {
    "scene": SceneInfo, "particles": Particles, "fluid": Fluid, "sph": SPH, "terms": Terms, "forces": Forces,
    "time": Time, "domain": Domain, "obstacles": Obstacle, "boundary": Boundary, "run": Run,
    "decomposition": DecompositionSection, "render": Render, "output": Output, "probes": Probe,
    "inlets": Inlet, "outlets": Outlet, "damping_zones": DampingZone,
}
LIST_ITEMS: dict[str, type] = {"fluid.blocks": Block, "domain.planes": Plane, "obstacles": Obstacle,
                               "render.cameras": RenderCamera, "probes": Probe, "inlets": Inlet, "outlets": Outlet,
                               "damping_zones": DampingZone}
# why the keys of a section (or of an array of tables) declared without ``control`` cannot change
# during a run
SECTION_CONTROL = {"scene": AT_START, "domain": WORLD, "obstacles": WORLD, "decomposition": PEERS,
                   "render": VIEWER, "output": OUTPUT, "fluid.blocks": PARTICLES, "domain.planes": WORLD,
                   "render.cameras": VIEWER, "probes": PROBES, "inlets": OPEN, "outlets": OPEN,
                   "damping_zones": WORLD}


@dataclass(frozen=True)
class Scene:
    scene: SceneInfo
    particles: Particles
    fluid: Fluid
    sph: SPH
    terms: Terms
    forces: Forces
    time: Time
    domain: Domain
    obstacles: tuple
    boundary: Boundary
    run: Run
    decomposition: DecompositionSection = DecompositionSection()
    render: Render = Render()
    output: Output = Output()
    probes: tuple = ()
    inlets: tuple = ()
    outlets: tuple = ()
    damping_zones: tuple = ()
    source: str = ""
    # where the run's coordinates start, in world coordinates (m): every position key holds
    # world - origin (``localised``); not a key, it follows from the domain
    origin: tuple = (0.0, 0.0, 0.0)

    @property
    def dim(self) -> int:
        return self.scene.dim

    def to_dict(self) -> dict:
        """Plain dict (TOML-serialisable) of every resolved key, positions in world coordinates."""
        world = shifted(self, self.origin) if any(self.origin) else self
        out = {}
        for f in dataclasses.fields(world):
            if f.name in ("source", "origin"):
                continue
            val = getattr(world, f.name)
            out[f.name] = [_plain(o) for o in val] if isinstance(val, tuple) else _plain(val)
        return out


def _plain(obj):
    if dataclasses.is_dataclass(obj):
        return {f.name: _plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (tuple, list)):
        return [_plain(o) for o in obj]
    return obj


def _type_name(t) -> str:
    return {"float": "a number", "int": "an integer", "bool": "true or false", "str": "a string",
            "tuple": "an array", "list": "an array of tables"}.get(t, t)


def _finite(x) -> bool:
    """math.isfinite that is False (instead of raising OverflowError) for ints beyond float range."""
    try:
        return math.isfinite(x)
    except OverflowError:
        return False


def _short(value, limit: int = 60) -> str:
    try:
        text = repr(value)
    except RecursionError:
        return "<an array nested too deeply>"
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _did_you_mean(name: str, allowed) -> str:
    """' (did you mean 'x'?)' for a close spelling of one of ``allowed``, else ''."""
    close = difflib.get_close_matches(str(name), [str(a) for a in allowed], n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _check_value(key: str, f: dataclasses.Field, value: Any):
    """Type- and range-check one value; return it normalised (ints to floats, lists to tuples)."""
    t = f.type if isinstance(f.type, str) else f.type.__name__
    meta = f.metadata
    if t == "float":
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SceneError(f"{key} = {_short(value)}: expected {_type_name(t)}")
        if not _finite(value):
            raise SceneError(f"{key} = {_short(value)}: expected a finite number")
        value = float(value)
        if not math.isfinite(value):
            raise SceneError(f"{key} = {_short(value)}: expected a finite number")
    elif t == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise SceneError(f"{key} = {_short(value)}: expected {_type_name(t)}")
    elif t == "bool":
        if not isinstance(value, bool):
            raise SceneError(f"{key} = {_short(value)}: expected {_type_name(t)}")
    elif t == "str":
        if not isinstance(value, str):
            raise SceneError(f"{key} = {_short(value)}: expected {_type_name(t)}")
    elif t == "tuple" and meta.get("rows"):  # a table: rows of finite numbers (their lengths: the key's own check)
        if not isinstance(value, (list, tuple)) or len(value) > meta["rows"]:
            raise SceneError(f"{key} = {_short(value)}: expected an array of at most {meta['rows']:,} rows")
        out = []
        for r, row in enumerate(value):
            if not isinstance(row, (list, tuple)) or not all(
                    not isinstance(e, bool) and isinstance(e, (int, float)) and _finite(e) for e in row):
                raise SceneError(f"{key}[{r}] = {_short(row)}: expected a row of finite numbers")
            out.append(tuple(float(e) for e in row))
        return tuple(out)
    elif t == "tuple":
        if not isinstance(value, (list, tuple)):
            raise SceneError(f"{key} = {_short(value)}: expected {_type_name(t)}")
        length = meta.get("length")
        if length and len(value) not in length:
            raise SceneError(f"{key} = {_short(value)}: expected {' or '.join(map(str, length))} components")
        elem_bool = isinstance(f.default, tuple) and f.default and isinstance(f.default[0], bool)
        elem_int = isinstance(f.default, tuple) and f.default and type(f.default[0]) is int
        out = []
        for e in value:
            if elem_int:
                if isinstance(e, bool) or not isinstance(e, int) or e < 0:
                    raise SceneError(f"{key} = {_short(value)}: expected an array of integers >= 0")
                out.append(e)
            elif elem_bool:
                if not isinstance(e, bool):
                    raise SceneError(f"{key} = {_short(value)}: expected an array of true/false")
                out.append(e)
            else:
                if isinstance(e, bool) or not isinstance(e, (int, float)) or not _finite(e):
                    raise SceneError(f"{key} = {_short(value)}: expected an array of finite numbers")
                out.append(float(e))
        return tuple(out)
    choices = meta.get("choices")
    if choices is not None and value not in choices:
        hint = _did_you_mean(value, choices) if isinstance(value, str) else ""
        raise SceneError(f"{key} = {_short(value)}: allowed values are {', '.join(repr(c) for c in choices)}{hint}")
    rng = meta.get("range")
    if rng is not None:
        lo, hi = rng
        if value > hi or value < lo or (meta.get("min_exclusive") and value == lo):
            left = "(" if meta.get("min_exclusive") else "["
            raise SceneError(f"{key} = {_short(value)}: allowed range is {left}{lo:g}, {hi:g}]")
    return value


def _build(cls, data: dict, path: str):
    if not isinstance(data, dict):
        raise SceneError(f"{path}: expected a table, got {_short(data)}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = [k for k in data if k not in fields]
    if unknown:
        raise SceneError(f"unknown key '{path}.{unknown[0]}'{_did_you_mean(unknown[0], fields)} (allowed in "
                         f"[{path}]: {', '.join(fields)})")
    values = {}
    for name, f in fields.items():
        key = f"{path}.{name}"
        if name not in data:
            continue
        value = data[name]
        item_cls = LIST_ITEMS.get(key)
        if item_cls is not None:
            if not isinstance(value, list):
                raise SceneError(f"{key} = {_short(value)}: expected an array of tables ([[{key}]])")
            values[name] = tuple(_build(item_cls, item, f"{key}[{i}]") for i, item in enumerate(value))
        else:
            values[name] = _check_value(key, f, value)
    return cls(**values)


def parse_override(text: str) -> tuple[list, Any]:
    """Split ``section.key=value`` (or ``fluid.blocks[0].velocity=[1,0,0]``) into a path and a value.

    The value is parsed as TOML; a bare word that is not valid TOML is taken as a string, so
    ``--set sph.kernel=cubic_spline`` works without quotes.
    """
    if "=" not in text:
        raise SceneError(f"--set {text!r}: expected section.key=value")
    lhs, rhs = text.split("=", 1)
    path = []
    for part in lhs.strip().split("."):
        if not part:
            raise SceneError(f"--set {text!r}: empty key segment")
        while "[" in part:
            name, rest = part.split("[", 1)
            if "]" not in rest:
                raise SceneError(f"--set {text!r}: missing ']' after '[{rest}'")
            index, part = rest.split("]", 1)
            if name:
                path.append(name)
            if not index.isdigit():
                raise SceneError(f"--set {text!r}: index [{index}] must be a non-negative integer")
            path.append(int(index))
        if part:
            path.append(part)
    try:
        value = tomllib.loads(f"v = {rhs.strip()}")["v"]
    except ValueError:  # TOMLDecodeError, or an integer longer than Python's int_max_str_digits
        value = rhs.strip()
    except RecursionError:
        raise SceneError(f"--set {_short(text)}: the value is nested too deeply") from None
    return path, value


def _unindexed(text: str, path: list, at: int):
    """--set reached an array of tables (path[:at]) with path[at], a key or a dotted digit, not an index."""
    table = ".".join(str(q) for q in path[:at])
    rest = ".".join(str(q) for q in path[at + 1 if path[at].isdigit() else at:])
    raise SceneError(f"--set {text!r}: '{table}' is an array of tables ([[{table}]]); name one by its index, "
                     f"e.g. {table}[0].{rest}")


def apply_override(data: dict, path: list, value, text: str):
    if len(path) < 2 or not isinstance(path[0], str):
        raise SceneError(f"--set {text!r}: expected section.key=value")
    if path[0] not in SECTIONS:
        raise SceneError(f"--set {text!r}: unknown section '{path[0]}'{_did_you_mean(path[0], SECTIONS)} "
                         f"(sections: {', '.join(SECTIONS)})")
    node = data
    for at, seg in enumerate(path[:-1]):
        if isinstance(seg, int):
            if not isinstance(node, list) or seg >= len(node):
                raise SceneError(f"--set {text!r}: index {seg} is out of range")
            node = node[seg]
        elif isinstance(node, list):                               # obstacles.0.density: an array of tables
            _unindexed(text, path, at)
        else:
            node = node.setdefault(seg, {})
        if not isinstance(node, (dict, list)):
            raise SceneError(f"--set {text!r}: '{seg}' is not a table")
    last = path[-1]
    if isinstance(node, list) and isinstance(last, str) and not last.isdigit():
        _unindexed(text, path, len(path) - 1)
    if isinstance(last, int) or not isinstance(node, dict):
        raise SceneError(f"--set {text!r}: expected section.key=value")
    node[last] = value


MAX_SCENE_BYTES = 4 << 20  # a scene is a short text file; anything larger is not one


def read_scene_file(path: str | Path) -> dict:
    """The TOML data of a scene file; SceneError (one line) for a file that cannot be read, is not
    UTF-8 text, is not TOML or nests too deeply."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_SCENE_BYTES + 1)
    except OSError as e:
        raise SceneError(f"cannot read scene file {str(path)!r}: {e.strerror}") from None
    if len(raw) > MAX_SCENE_BYTES:
        raise SceneError(f"{path}: larger than {MAX_SCENE_BYTES >> 20} MiB; a scene is a short TOML text file")
    try:
        text = raw.decode("utf-8-sig")  # a byte-order mark (editors on Windows write one) is not TOML: dropped
    except UnicodeDecodeError as e:
        raise SceneError(f"{path}: not a text file (byte 0x{raw[e.start]:02x} at offset {e.start} is not UTF-8); "
                         "a scene is a TOML text file") from None
    if "\0" in text:
        raise SceneError(f"{path}: not a text file (a NUL byte at offset {text.index(chr(0))}); a scene is a TOML "
                         "text file")
    try:
        return tomllib.loads(text)
    except ValueError as e:  # TOMLDecodeError, or an integer longer than int_max_str_digits
        raise SceneError(f"{path}: not valid TOML: {e}") from None
    except RecursionError:
        raise SceneError(f"{path}: not a scene: its arrays or tables are nested too deeply to read") from None


def load_scene(path: str | Path, overrides: list[str] = (), backend: str = "cpu") -> Scene:
    """Read, override and validate a scene file; ``backend`` (cpu, cuda): whose host memory the
    resource check estimates (HOST_BYTES_PER_PARTICLE)."""
    path = Path(path)
    data = read_scene_file(path)
    written_dim = _written_dim(data)
    for text_ in overrides:
        p, v = parse_override(text_)
        apply_override(data, p, v, text_)
    new_dim = _written_dim(data)
    if written_dim is None or new_dim is None or new_dim == written_dim:
        return scene_from_dict(data, source=str(path), backend=backend)
    prefix = f"--set scene.dim={new_dim} on {path}, written for {written_dim}D"
    try:
        scene = scene_from_dict(data, source=str(path), backend=backend)
    except SceneError as e:  # 2D -> 3D: a 2-component vector the overrides did not replace
        raise SceneError(f"{prefix}: {e}") from None
    _check_dim_change(scene, prefix)
    return scene


def _written_dim(data: dict):
    info = data.get("scene", {})
    dim = info.get("dim", 3) if isinstance(info, dict) else None
    return dim if dim in (2, 3) and not isinstance(dim, bool) else None


def _check_dim_change(scene: Scene, prefix: str):
    """A 3D scene run in 2D (--set scene.dim=2) drops every z: refused while any vector of it has a
    z component (tiny.toml's 498 particles would become 57), so a 2D run of it needs every vector
    overridden as well. 2D -> 3D needs every vector in 3 components, which validation checks."""
    if scene.dim != 2:
        return
    for key, value in _vectors(scene):
        if value[2]:
            raise SceneError(f"{prefix}: {key} = {_toml_value(value)} has a z component a 2D run would drop; "
                             "write a 2D scene (e.g. configs/dam_break_2d.toml) instead of changing scene.dim")


def _vectors(scene: Scene):
    """(key, value) of every 2-or-3-component vector of the scene."""
    def walk(obj, path):
        for f in dataclasses.fields(obj):
            val = getattr(obj, f.name)
            if f.metadata.get("length") == VEC:
                yield f"{path}.{f.name}", val
            elif isinstance(val, tuple) and val and dataclasses.is_dataclass(val[0]):
                for i, o in enumerate(val):
                    yield from walk(o, f"{path}.{f.name}[{i}]")
    for name in SECTIONS:
        val = getattr(scene, name)
        if isinstance(val, tuple):
            for i, o in enumerate(val):
                yield from walk(o, f"{name}[{i}]")
        else:
            yield from walk(val, name)


def scene_from_dict(data: dict, source: str = "", backend: str = "cpu") -> Scene:
    unknown = [k for k in data if k not in SECTIONS]
    if unknown:
        raise SceneError(f"unknown section [{unknown[0]}]{_did_you_mean(unknown[0], SECTIONS)} (sections: "
                         f"{', '.join(SECTIONS)})")
    parts = {}
    for name, cls in SECTIONS.items():
        if name == "obstacles":
            raw = data.get("obstacles", [])
            if not isinstance(raw, list):
                raise SceneError(f"obstacles = {raw!r}: expected an array of tables ([[obstacles]])")
            parts[name] = tuple(_build(Obstacle, o, f"obstacles[{i}]") for i, o in enumerate(raw))
        elif name == "probes":
            parts[name] = _build_tables(Probe, name, data.get(name, []), ("name", "at"),
                                        ', e.g. name = "p1", at = [0.5, 0.1]')
        elif name in ("inlets", "outlets"):
            parts[name] = _build_tables(cls, name, data.get(name, []), ("min", "max"), ", the corners of its zone")
        elif name == "damping_zones":
            parts[name] = _build_tables(cls, name, data.get(name, []), ("min", "max", "direction", "rate"),
                                        ", e.g. min = [1, 0], max = [2, 0.3], direction = [1, 0], rate = 20")
        else:
            parts[name] = _build(cls, data.get(name, {}), name)
    scene = Scene(**parts, source=source)
    return localised(_check_combinations(_pad_vectors(scene), backend=backend))


def scene_origin(s: Scene) -> tuple:
    """The origin of a run's coordinates (m): (0, 0, 0) for a domain within twice its size Q of the
    world's origin (every scene of configs/, whose results therefore stay as they were), else the
    domain's centre rounded down to a multiple of Q, a power of two at least as large as the domain's
    largest edge (down: a tank in [0, L] moved by a multiple of Q gets exactly that multiple). float32 keeps ~7 significant digits of a coordinate, so a scene 1e6 m away would
    lose all of them below 0.06 m: relative to this origin it computes exactly what the same scene
    computes at the world's origin, and x - origin is exact in float64 (the origin is a multiple of
    Q, coarser than the ulp of any coordinate of the domain)."""
    dom = s.domain
    centre = ([(lo + hi) / 2 for lo, hi in zip(dom.bounds_min, dom.bounds_max)] if dom.container == "none"
              else list(dom.center))
    Q = 2.0 ** math.ceil(math.log2(max(max(_domain_extent(s)), 1e-300)))
    return tuple(0.0 if abs(c) <= 2 * Q else Q * math.floor(c / Q) for c in centre)


def shifted(s: Scene, offset) -> Scene:
    """``s`` with every position key (``spec(position=True)``) moved by ``offset`` (m) and its origin
    by -offset, so that origin + position stays where it was; a block's or obstacle's coordinates in
    the container's frame move with the container and are left alone."""
    offset = tuple(float(o) for o in offset)

    def move(obj):
        if getattr(obj, "frame", "world") != "world":
            return obj
        changes = {}
        for f in dataclasses.fields(obj):
            val = getattr(obj, f.name)
            if f.metadata.get("position"):
                changes[f.name] = tuple(v + o for v, o in zip(val, offset))
            elif isinstance(val, tuple) and val and dataclasses.is_dataclass(val[0]):
                changes[f.name] = tuple(move(o) for o in val)
        return dataclasses.replace(obj, **changes) if changes else obj

    new = {name: tuple(move(o) for o in val) if isinstance(val, tuple) else move(val)
           for name in SECTIONS for val in [getattr(s, name)]}
    return dataclasses.replace(s, **new, origin=tuple(o - d for o, d in zip(s.origin, offset)))


def localised(s: Scene) -> Scene:
    """``s`` in its run's coordinates: positions relative to ``scene_origin`` (``s`` itself when
    that is the world's origin). Idempotent: a localised scene's own origin is (0, 0, 0)."""
    o = scene_origin(s)
    return shifted(s, tuple(-c for c in o)) if any(o) else s


def _pad(vec: tuple, fill=0.0) -> tuple:
    return tuple(vec) + (fill,) * (3 - len(vec))


def _pad_vectors(scene: Scene) -> Scene:
    """Give every 2-component vector a z component (0 / false); in 3D scenes reject 2-vectors."""
    def fix(obj, path):
        changes = {}
        for f in dataclasses.fields(obj):
            val = getattr(obj, f.name)
            if f.metadata.get("length") == VEC and isinstance(val, tuple) and len(val) == 2:
                if scene.dim == 3:
                    raise SceneError(f"{path}.{f.name} = {list(val)!r}: a 3D scene needs 3 components")
                changes[f.name] = _pad(val, False if isinstance(val[0], bool) else 0.0)
            elif isinstance(val, tuple) and val and dataclasses.is_dataclass(val[0]):
                changes[f.name] = tuple(fix(o, f"{path}.{f.name}[{i}]") for i, o in enumerate(val))
        return dataclasses.replace(obj, **changes) if changes else obj

    new = {}
    for name in SECTIONS:
        val = getattr(scene, name)
        if isinstance(val, tuple):
            new[name] = tuple(fix(o, f"{name}[{i}]") for i, o in enumerate(val))
        else:
            new[name] = fix(val, name)
    return dataclasses.replace(scene, **new)


def mesh_path(scene: Scene, obstacle) -> Path:
    """A mesh obstacle's file: relative to the scene file's folder (or the working folder)."""
    path = Path(obstacle.file)
    if not path.is_absolute() and scene.source:
        path = Path(scene.source).parent / path
    return path


MESH_SUFFIXES = (".stl", ".obj", ".ply")


ARTIFICIAL_ALPHA_MAX = 10.0  # sph.alpha's own bound


def artificial_alpha(s) -> float:
    """The artificial viscosity coefficient of scene ``s``: sph.alpha, or, where sph.alpha_nu > 0, the
    alpha whose shear viscosity alpha c0 h / (2 (dim + 2)) is alpha_nu at this spacing (Monaghan 2005,
    "Smoothed particle hydrodynamics", Rep. Prog. Phys. 68, 1703, sec. 4.1; h = support / 2, as in
    physics/viscosity.py)."""
    if s.sph.alpha_nu <= 0.0:
        return s.sph.alpha
    return s.sph.alpha_nu / _shear_viscosity_per_alpha(s)


def _shear_viscosity_per_alpha(s) -> float:
    """c0 h / (2 (dim + 2)): the shear viscosity (m^2/s) of the artificial viscosity per unit alpha
    (Monaghan 2005, sec. 4.1; h = support / 2, as in physics/viscosity.py)."""
    h = 0.5 * s.sph.support * s.particles.spacing
    return s.sph.sound_speed * h / (2.0 * (s.dim + 2))


def shear_viscosity(s) -> float:
    """The kinematic viscosity (m^2/s) that scene ``s``'s viscosity model acts with in a shear flow:
    sph.nu for the Mueller and Morris viscosities, alpha c0 h / (2 (dim + 2)) for the artificial one
    (Monaghan 2005, as ``artificial_alpha``), 0 without viscosity. What another code is given to run
    the same fluid (``sph bench --until --external``)."""
    if s.sph.viscosity in ("muller", "morris"):
        return s.sph.nu
    if s.sph.viscosity == "artificial":
        return artificial_alpha(s) * _shear_viscosity_per_alpha(s)
    return 0.0


def check_mesh_file(path: Path, key: str):
    """A mesh obstacle's file holds a closed-enough triangle mesh that PyVista reads; SceneError
    (one line) for an empty, truncated, corrupt or unknown file. VTK's own error printing is
    silenced meanwhile: the SceneError says it once."""
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise SceneError(f"{key}: a mesh file must end in {', '.join(MESH_SUFFIXES)}, not {path.suffix!r}")
    if path.stat().st_size == 0:
        raise SceneError(f"{key}: the file is empty")
    try:
        mesh = read_mesh(path)
        n_triangles = mesh.n_cells
        points = np.asarray(mesh.points, dtype=np.float64)
    except Exception as e:  # VTK and PyVista raise many kinds for files they cannot parse
        raise SceneError(f"{key}: not a readable mesh ({type(e).__name__}: {str(e)[:120]})") from None
    if n_triangles == 0:
        raise SceneError(f"{key}: no triangles could be read (empty, truncated or corrupt {path.suffix} file)")
    if not np.isfinite(points).all():
        raise SceneError(f"{key}: the mesh has non-finite vertex coordinates")
    if np.ptp(points, axis=0).max() <= 0:
        raise SceneError(f"{key}: the mesh has no extent (every vertex at one point)")


def _check_combinations(s: Scene, files: bool = True, backend: str = "cpu") -> Scene:
    """Cross-key rules: each error names the keys involved and what would be allowed. ``files``
    False (a live change, ``live_change``): the mesh files and the memory estimate, which no live key
    changes, are not checked again (the running run itself holds memory the estimate would count as
    missing)."""
    dom = s.domain
    if -1.0 < s.run.neighbour_skin < 0.0:
        raise SceneError(f"run.neighbour_skin = {s.run.neighbour_skin:g}: a skin is from 0 to 1 (of the support "
                         "radius), or -1 for auto")
    if s.run.neighbour_skin > 0.0:
        if s.run.neighbours != "lists":
            raise SceneError(f"run.neighbour_skin = {s.run.neighbour_skin:g}: reused lists need run.neighbours = "
                             f"'lists', not {s.run.neighbours!r} (or set run.neighbour_skin = 0)")
        if backend != "cpu":
            raise SceneError(f"run.neighbour_skin = {s.run.neighbour_skin:g}: reused lists are built on the CPU "
                             f"backend only, not {backend!r} (set run.neighbour_skin = 0)")
    if s.dim == 2:
        if dom.container == "cylinder":
            raise SceneError("domain.container = 'cylinder': not available in 2D scenes (use box or sphere)")
        if dom.rotation[0] or dom.rotation[1]:
            raise SceneError(f"domain.rotation = {list(dom.rotation)!r}: 2D scenes rotate about z only")
        if dom.periodic[2]:
            raise SceneError("domain.periodic: a 2D scene cannot be periodic along z")
        for name in ("gravity", "external"):
            if getattr(s.forces, name)[2] != 0.0:
                raise SceneError(f"forces.{name} = {list(getattr(s.forces, name))!r}: z must be 0 in 2D")
    if any(dom.periodic):
        if dom.container not in ("box", "none"):
            raise SceneError(f"domain.periodic = {list(dom.periodic)!r}: periodic axes need container = 'box' "
                             f"or 'none', not {dom.container!r}")
        if any(dom.rotation) or dom.scale != 1.0:
            raise SceneError(f"domain.periodic = {list(dom.periodic)!r}: a periodic container cannot be rotated or "
                             "scaled (domain.rotation = [0, 0, 0], domain.scale = 1)")
        H = s.sph.support * s.particles.spacing
        skin = max(s.run.neighbour_skin, 0.0)  # the automatic skin fits itself (list_skin)
        for d in range(s.dim):
            if dom.periodic[d]:
                length = _period(s, d)
                if length < 3.0 * H:
                    raise SceneError(f"domain.periodic: axis {'xyz'[d]} is {length:g} m long, shorter than 3 support "
                                     f"radii (3 x sph.support x particles.spacing = {3.0 * H:g} m); lengthen it or "
                                     "refine particles.spacing")
                if length < 3.0 * H * (1.0 + skin):
                    raise SceneError(f"run.neighbour_skin = {skin:g}: the lists reach H (1 + skin) = {H * (1 + skin):g} "
                                     f"m, and periodic axis {'xyz'[d]} ({length:g} m) must hold 3 of them; lower "
                                     f"the skin to {max(length / (3.0 * H) - 1.0, 0.0):.3f} or less, or set -1 (auto)")
    if dom.container == "none":
        lo, hi = dom.bounds_min, dom.bounds_max
        if any(hi[d] <= lo[d] for d in range(s.dim)):
            raise SceneError(f"domain.bounds_max = {list(hi)!r}: must exceed domain.bounds_min = {list(lo)!r} on "
                             "every axis when domain.container = 'none'")
    if dom.container == "box" and any(dom.size[d] <= 0 for d in range(s.dim)):
        raise SceneError(f"domain.size = {list(dom.size)!r}: box edge lengths must be positive")
    if dom.container == "cylinder" and (dom.size[0] <= 0 or dom.size[1] <= 0):
        raise SceneError(f"domain.size = {list(dom.size)!r}: cylinder needs (diameter, height) > 0")
    dims = s.decomposition.dims
    if any(dims) and (not all(dims) or (s.dim == 2 and dims[2] != 1)):
        raise SceneError(f"decomposition.dims = {list(dims)!r}: give all three counts >= 1 (pz = 1 in 2D), "
                         "or [0, 0, 0] to choose them from the peer count")
    obstacles = []
    for i, ob in enumerate(s.obstacles):
        if ob.shape == "mesh" and files:
            if s.dim != 3:
                raise SceneError(f"obstacles[{i}].shape = 'mesh': mesh obstacles need a 3D scene")
            path = mesh_path(s, ob)
            if path.is_dir():
                raise SceneError(f"obstacles[{i}].file = {ob.file!r}: {path} is a folder, not a mesh file (give an "
                                 f"{', '.join(MESH_SUFFIXES)} file)")
            if not path.is_file():
                raise SceneError(f"obstacles[{i}].file = {ob.file!r}: no such file ({path})")
            check_mesh_file(path, f"obstacles[{i}].file = {ob.file!r}")
            try:  # its distance grid's size at this scale and spacing, and whether it is closed
                check_mesh_obstacle(s, i, path)
            except MeshCheckError as e:
                raise SceneError(str(e)) from None
            ob = dataclasses.replace(ob, file=str(path.resolve()))  # resolved: scene.toml works anywhere
        obstacles.append(ob)
    s = dataclasses.replace(s, obstacles=tuple(obstacles))
    names = [c.name for c in s.render.cameras]
    if len(set(names)) != len(names) or "default" in names:
        raise SceneError(f"render.cameras: names must be unique and not 'default', got {names!r}")
    if s.render.camera not in ["default"] + names:
        raise SceneError(f"render.camera = {s.render.camera!r}: allowed values are 'default'"
                         + "".join(f", {n!r}" for n in names))
    for i, c in enumerate(s.render.cameras):
        if all(a == b for a, b in zip(c.eye, c.target)):
            raise SceneError(f"render.cameras[{i}].eye = {list(c.eye)!r}: must differ from its target")
    lo, hi = s.render.range
    if (lo, hi) != (0.0, 0.0) and not hi > lo:
        raise SceneError(f"render.range = {[lo, hi]!r}: high must exceed low (or [0, 0] for the default)")
    name = s.scene.name
    if len(name) > 200 or any(unicodedata.category(c)[0] == "C" for c in name):
        # the name is printed in logs and summaries: a newline in it could forge a line of them
        raise SceneError(f"scene.name = {_short(name)}: at most 200 characters, none of them control or format "
                         "characters (newlines, tabs, direction overrides)")
    if not s.fluid.blocks:
        raise SceneError("fluid.blocks: a scene needs at least one [[fluid.blocks]] table")
    for i, b in enumerate(s.fluid.blocks):
        key = f"fluid.blocks[{i}]"
        if b.shape == "box" and any(b.max[d] <= b.min[d] for d in range(s.dim)):
            raise SceneError(f"{key}.max = {list(b.max)!r}: must exceed {key}.min = {list(b.min)!r} on every axis")
        if b.shape == "sphere" and b.radius <= 0:
            raise SceneError(f"{key}.radius = {b.radius!r}: a sphere block needs a positive radius")
        if b.lattice == "polar" and b.shape != "sphere":
            raise SceneError(f"{key}.lattice = 'polar': fills a sphere block (rings or shells about its centre); "
                             f"this block's shape is {b.shape!r} (use lattice = 'cartesian')")
    for i, pl in enumerate(s.domain.planes):
        if math.hypot(*pl.normal) == 0:
            raise SceneError(f"domain.planes[{i}].normal = {list(pl.normal)!r}: must be non-zero")
    for key, item in [(f"domain.planes[{i}]", pl) for i, pl in enumerate(s.domain.planes)] + \
            [(f"obstacles[{i}]", ob) for i, ob in enumerate(s.obstacles)]:
        _check_motion(s, key, item)
    for i, ob in enumerate(s.obstacles):
        if ob.shape == "box" and not all(ob.size[d] > 0.0 for d in range(s.dim)):
            # a negative edge made a body of negative mass that carved nothing, a zero one a body of no mass
            raise SceneError(f"obstacles[{i}].size = {list(ob.size[: s.dim])!r}: every edge length must be > 0 (m)")
        if ob.density > 0.0:
            _check_floating(s, f"obstacles[{i}]", ob)
        elif any(ob.free_rotation):
            raise SceneError(f"obstacles[{i}].free_rotation = {list(ob.free_rotation)!r}: only a floating body turns "
                             f"freely (give obstacles[{i}].density > 0, or angular_velocity for a prescribed turn)")
    if s.sph.solver == "dfsph" and s.time.integrator != "symplectic_euler":
        raise SceneError(f"time.integrator = {s.time.integrator!r}: sph.solver = 'dfsph' integrates with "
                         "'symplectic_euler' (its pressure solve predicts v* = v + dt a and then moves x by dt v*)")
    if s.sph.viscosity_switch != "none" and s.sph.viscosity != "artificial":
        raise SceneError(f"sph.viscosity_switch = {s.sph.viscosity_switch!r}: it scales the artificial viscosity, but "
                         f"sph.viscosity = {s.sph.viscosity!r} (use sph.viscosity = 'artificial', or "
                         "sph.viscosity_switch = 'none')")
    if s.sph.alpha_nu > 0.0:
        if s.sph.viscosity != "artificial":
            raise SceneError(f"sph.alpha_nu = {s.sph.alpha_nu!r}: it sets the artificial viscosity, but sph.viscosity "
                             f"= {s.sph.viscosity!r} (use sph.viscosity = 'artificial', or sph.nu for "
                             f"{s.sph.viscosity!r})")
        alpha = artificial_alpha(s)
        if alpha > ARTIFICIAL_ALPHA_MAX:
            raise SceneError(f"sph.alpha_nu = {s.sph.alpha_nu!r}: at sph.sound_speed = {s.sph.sound_speed!r} and a "
                             f"support of {s.sph.support!r} spacings of {s.particles.spacing!r} m it needs alpha = "
                             f"{alpha:.4g}, above {ARTIFICIAL_ALPHA_MAX:g} (lower it, or raise the spacing or the "
                             "sound speed)")
    if s.sph.solver == "dfsph" and s.sph.density == "continuity":
        raise SceneError("sph.density = 'continuity': sph.solver = 'dfsph' solves for the summation density "
                         "(use sph.density = 'summation', or sph.solver = 'wcsph')")
    if s.forces.hydrostatic == "removed":
        # the modified pressure has no hydrostatic part only where no free surface sets p = 0 somewhere
        where = ("sph.clamp_negative_pressure = true (a free surface)" if s.sph.clamp_negative_pressure else
                 "domain.container = 'none' (no closed container)" if dom.container == "none" else
                 f"domain.periodic = {list(dom.periodic[: s.dim])!r}" if any(dom.periodic[: s.dim]) else
                 "inlets or outlets" if (s.inlets or s.outlets) else "")
        if where:
            raise SceneError(f"forces.hydrostatic = 'removed': only for a closed container full of fluid (no free "
                             f"surface), but the scene has {where}; use forces.hydrostatic = 'resolved'")
    if s.sph.pressure_gradient == "difference" and s.sph.solver == "dfsph":
        raise SceneError("sph.pressure_gradient = 'difference': a WCSPH form (the forces pass); sph.solver = 'dfsph' "
                         "solves its pressure and applies it with its own symmetric term (use 'symmetric', or "
                         "sph.solver = 'wcsph')")
    floating = [i for i, ob in enumerate(s.obstacles) if ob.density > 0.0]
    if s.sph.pressure_gradient == "difference" and floating and s.sph.body_force != "traction":
        # the walls push a bulk particle with the hydrostatic part only: their reaction is no force on the body
        raise SceneError(f"sph.pressure_gradient = 'difference' with floating bodies (obstacles[{floating[0]}]) needs "
                         f"sph.body_force = 'traction': in that form the walls do not push the particles with their "
                         f"pressure, so the reaction to that push is not the fluid's force on the body; the scene "
                         f"has sph.body_force = {s.sph.body_force!r}")
    if s.sph.body_force == "traction" and floating and s.sph.pressure_gradient != "difference":
        # the fit reads the pressures next to the body, which the symmetric form's wall push does not hold on
        # the hydrostatic line (a held square log at 5 spacings' depth: 1,400-1,500 Pa against 1,000)
        raise SceneError(f"sph.body_force = 'traction' needs sph.pressure_gradient = 'difference' (and "
                         f"terms.shifting > 0): it fits the pressure of the particles next to the body, and with the "
                         f"symmetric form those are the wall push's balance, not the fluid's pressure (a held square "
                         f"log's buoyancy came out 35 % high); the scene has sph.pressure_gradient = "
                         f"{s.sph.pressure_gradient!r}")
    if s.sph.body_force == "traction" and floating and s.terms.wall_friction > 0.0:
        raise SceneError(f"sph.body_force = 'traction' does not include the walls' turbulent friction "
                         f"(terms.wall_friction = {s.terms.wall_friction!r}) in a floating body's force; use "
                         f"sph.body_force = 'reaction' or terms.wall_friction = 0")
    if s.sph.body_force == "traction" and floating:
        from sphcore.physics.traction import MAX_SURFACE_POINTS, surface_point_count
        for i in floating:
            ob = s.obstacles[i]
            points = surface_point_count(ob.shape, s.dim, ob.radius, ob.size, s.particles.spacing)
            if points > MAX_SURFACE_POINTS:
                what = (f"obstacles[{i}].radius = {ob.radius!r}" if ob.shape == "sphere" else
                        f"obstacles[{i}].size = {list(ob.size[: s.dim])!r}")
                raise SceneError(f"sph.body_force = 'traction': {what} at particles.spacing = "
                                 f"{s.particles.spacing!r} needs about {points:,} points on the body's surface (two "
                                 f"per spacing), at most {MAX_SURFACE_POINTS:,}; use a coarser spacing or a smaller "
                                 f"body, or sph.body_force = 'reaction' with sph.pressure_gradient = 'symmetric'")
    if s.sph.pressure_gradient == "difference" and s.terms.shifting <= 0.0:
        # nothing else holds the particles apart: they pair and clump (a dam break reached the speed of sound)
        raise SceneError("sph.pressure_gradient = 'difference' needs terms.shifting > 0 (typically 1-2): a uniform "
                         "pressure does not push the particles apart in that form, so only shifting keeps them "
                         f"ordered; the scene has terms.shifting = {s.terms.shifting!r}")
    if s.sph.background_pressure > 0.0:
        # a free surface under a background pressure has nothing to hold it: the fluid flies apart
        where = ("sph.solver = 'dfsph' (its pressure is solved, not an EOS)" if s.sph.solver == "dfsph" else
                 "sph.clamp_negative_pressure = true (a free surface)" if s.sph.clamp_negative_pressure else
                 "inlets or outlets (their pressure is set, not an EOS)" if (s.inlets or s.outlets) else "")
        if where:
            raise SceneError(f"sph.background_pressure = {s.sph.background_pressure!r}: only for a closed WCSPH flow, "
                             f"but the scene has {where}; set sph.background_pressure = 0")
    if s.sph.viscosity in ("muller", "morris") and s.sph.nu <= 0:
        raise SceneError(f"sph.nu = {s.sph.nu!r}: viscosity = {s.sph.viscosity!r} needs nu > 0")
    if s.fluid.initial_flow == "taylor_green":
        if s.dim != 2 or not (dom.periodic[0] and dom.periodic[1]):
            raise SceneError("fluid.initial_flow = 'taylor_green': needs dim = 2 and domain.periodic = [true, true]")
    if s.time.mode == "fixed" and s.time.integrator == "leapfrog" and s.time.dt <= 0:
        raise SceneError(f"time.dt = {s.time.dt!r}: must be positive")
    _check_probes(s)
    _check_open_boundaries(s)
    _check_damping_zones(s)
    if files:
        _check_resources(s, backend=backend)
    return s


def _check_motion(s, key: str, item):
    """A wall's prescribed motion (sphcore/motion.py): in the scene's plane in 2D, an oscillation
    with a frequency, and a frequency with an amplitude."""
    if s.dim == 2:
        for name in ("velocity", "amplitude", "pivot"):
            value = getattr(item, name)
            if len(value) == 3 and value[2] != 0.0:
                raise SceneError(f"{key}.{name} = {list(value)!r}: z must be 0 in 2D")
        for name in ("angular_velocity", "angular_amplitude"):
            value = getattr(item, name)
            if any(value[:2]):
                raise SceneError(f"{key}.{name} = {list(value)!r}: a 2D scene turns about z only, e.g. [0, 0, 30]")
    oscillating = any(item.amplitude) or any(item.angular_amplitude)
    if oscillating and item.frequency == 0.0:
        name = "amplitude" if any(item.amplitude) else "angular_amplitude"
        value = list(getattr(item, name)[: s.dim] if name == "amplitude" else getattr(item, name))
        raise SceneError(f"{key}.{name} = {value!r}: an oscillation needs {key}.frequency > 0 (Hz)")
    if item.frequency > 0.0 and not oscillating:
        raise SceneError(f"{key}.frequency = {item.frequency!r}: an oscillation needs a non-zero {key}.amplitude (m) or "
                         f"{key}.angular_amplitude (degrees)")
    _check_rotation(s, key, item)
    if item.path:
        _check_path(s, key, item)
    from sphcore.motion import Motion
    motion = Motion.of(item)
    reach = math.hypot(*_domain_extent(s)) + math.hypot(*item.pivot)  # no wall point farther from the pivot
    speed = motion.largest_speed(reach) if motion is not None else 0.0
    if not speed < s.sph.sound_speed:  # NaN too (a path of +-1.7e308 m: inf - inf), which >= let through
        what = "path" if item.path else "velocity / amplitude / frequency"
        why = "" if speed == speed else " (its rows overflow a float)"
        raise SceneError(f"{key}.{what}: the wall moves at up to {speed:.3g} m/s{why}, not below "
                         f"sph.sound_speed = {s.sph.sound_speed:g} m/s; a weakly compressible fluid needs walls "
                         "slower than sound (10 x slower for 1 % density error)")
    if motion is not None and s.sph.solver != "wcsph":
        raise SceneError(f"{key}.{'path' if item.path else 'velocity / amplitude'}: moving walls need sph.solver = "
                         "'wcsph' (DFSPH's solves do not see the walls move)")


def _check_rotation(s, key: str, item):
    """A prescribed rotation turns about one axis (angular_velocity and angular_amplitude parallel),
    not with a path (translation only) or a floating body (it keeps its orientation), and not a
    mesh obstacle (its distance grid is laid out in the world's axes)."""
    W, B = item.angular_velocity, item.angular_amplitude
    if not (any(W) or any(B)):
        return
    cross = (W[1] * B[2] - W[2] * B[1], W[2] * B[0] - W[0] * B[2], W[0] * B[1] - W[1] * B[0])
    if any(abs(c) > 1e-12 * math.hypot(*W) * math.hypot(*B) for c in cross):
        raise SceneError(f"{key}.angular_velocity = {list(W)!r} and {key}.angular_amplitude = {list(B)!r}: a wall turns "
                         "about one axis; give them the same direction")
    if item.path:
        raise SceneError(f"{key}.path: a path translates only; give the rotation without a path, or the path "
                         "without angular_velocity / angular_amplitude")
    if getattr(item, "density", 0.0) > 0.0:
        raise SceneError(f"{key}.angular_velocity / angular_amplitude: a floating body is turned by the fluid, not "
                         f"by prescription (free it with {key}.free_rotation)")
    if getattr(item, "shape", "") == "mesh":
        raise SceneError(f"{key}.angular_velocity / angular_amplitude: a mesh obstacle cannot turn (its signed "
                         "distance grid is laid out along the world's axes); it can translate")


def _check_path(s, key: str, item):
    """A tabulated motion: rows [t, x, y(, z)] of the scene's dimension, times increasing from 0 or later,
    starting at zero displacement, and no velocity or oscillation besides."""
    if any(item.velocity) or any(item.amplitude) or item.frequency > 0.0:
        raise SceneError(f"{key}.path: give a wall either a path or velocity / amplitude / frequency, not both")
    rows = item.path
    if len(rows) < 2:
        raise SceneError(f"{key}.path = {_short([list(r) for r in rows])}: a path needs at least 2 rows [t, x, y"
                         f"{', z' if s.dim == 3 else ''}]")
    width = s.dim + 1
    for r, row in enumerate(rows):
        if len(row) != width:
            raise SceneError(f"{key}.path[{r}] = {_short(list(row))}: expected {width} numbers, [t, x, y"
                             f"{', z' if s.dim == 3 else ''}] (s, m)")
    times = [row[0] for row in rows]
    if times[0] < 0.0:
        raise SceneError(f"{key}.path[0] = {_short(list(rows[0]))}: the first time must be >= 0 s")
    for r in range(1, len(rows)):
        if not times[r] > times[r - 1]:
            raise SceneError(f"{key}.path[{r}] = {_short(list(rows[r]))}: times must increase (the row before is at "
                             f"t = {times[r - 1]:g} s)")
    if any(rows[0][1:]):
        raise SceneError(f"{key}.path[0] = {_short(list(rows[0]))}: the first row's displacement must be 0 (the "
                         "path is measured from where the scene puts the wall)")


def _check_floating(s, key: str, ob):
    """A floating body (sphcore/motion.py FloatingBody): a sphere or box, not also moved by prescription,
    with the weakly compressible solver (DFSPH's pressure solve does not see the body move)."""
    if ob.shape == "mesh":
        raise SceneError(f"{key}.density = {ob.density!r}: only sphere and box obstacles can float (a mesh has no "
                         "volume here)")
    if any(ob.velocity) or any(ob.amplitude) or ob.path:
        raise SceneError(f"{key}.density = {ob.density!r}: a floating body is moved by the fluid; give it no "
                         f"{key}.velocity, {key}.amplitude or {key}.path")
    if s.sph.solver != "wcsph":
        raise SceneError(f"{key}.density = {ob.density!r}: floating bodies need sph.solver = 'wcsph'")
    if ob.density < 0.1 * s.fluid.rest_density:
        raise SceneError(f"{key}.density = {ob.density!r}: below 0.1 x fluid.rest_density = "
                         f"{0.1 * s.fluid.rest_density:g} kg/m^3; the fluid moves a body this light through an explicit "
                         "coupling that is unstable when the body is much lighter than the fluid it displaces")
    if s.dim == 2 and (ob.free_rotation[0] or ob.free_rotation[1]):
        raise SceneError(f"{key}.free_rotation = {list(ob.free_rotation)!r}: a 2D body turns about z only, "
                         "[false, false, true]")
    if not any(ob.free[: s.dim]) and not any(ob.free_rotation):
        raise SceneError(f"{key}.free = {list(ob.free[:s.dim])!r}: a floating body needs at least one free axis "
                         f"(or {key}.free_rotation; or density = 0 for a fixed obstacle)")
    # a body larger than the domain, or starting outside it, only fails later (its mass overflowed, or it
    # "left the domain" at step 0)
    across = 2.0 * ob.radius if ob.shape == "sphere" else math.hypot(*ob.size[: s.dim])
    extent = math.hypot(*_domain_extent(s)[: s.dim])
    if not across < extent:
        what = f"{key}.radius = {ob.radius!r}" if ob.shape == "sphere" else f"{key}.size = {list(ob.size[: s.dim])!r}"
        raise SceneError(f"{what}: a floating body {across:.3g} m across, not smaller than the domain "
                         f"({extent:.3g} m across its box)")
    lo, hi = _domain_box(s)
    if ob.frame == "world" and not all(lo[d] <= ob.center[d] <= hi[d] for d in range(s.dim)):
        o = s.origin  # the scene file's coordinates in the message, not the run's
        raise SceneError(f"{key}.center = {[ob.center[d] + o[d] for d in range(s.dim)]!r}: outside the domain's box "
                         f"{[lo[d] + o[d] for d in range(s.dim)]!r} .. {[hi[d] + o[d] for d in range(s.dim)]!r}; a "
                         "floating body starts inside the domain")


def _build_tables(cls, name: str, raw, required: tuple, hint: str) -> tuple:
    """An array of tables ([[probes]], [[inlets]], [[outlets]]): each built like any table, and the
    ``required`` keys given (a probe at a default point would measure somewhere nobody asked for, a
    zone at a default box would be nowhere)."""
    if not isinstance(raw, list):
        raise SceneError(f"{name} = {_short(raw)}: expected an array of tables ([[{name}]])")
    items = []
    for i, item in enumerate(raw):
        built = _build(cls, item, f"{name}[{i}]")
        for key in required:
            if key not in item:
                raise SceneError(f"{name}[{i}]: no {key} given (each [[{name}]] needs {' and '.join(required)}{hint})")
        items.append(built)
    return tuple(items)


def _axis_of(s: Scene, key: str, vec) -> int:
    """The one axis ``vec`` lies along (an open boundary's flow, a damping zone's direction), or SceneError."""
    along = [d for d in range(s.dim) if vec[d] != 0.0]
    if len(along) != 1 or any(vec[s.dim:]):
        raise SceneError(f"{key} = {list(vec[: s.dim])!r}: must lie along one axis (one nonzero component; the "
                         "zones are axis-aligned boxes)")
    return along[0]


def _check_open_boundaries(s: Scene):
    """[[inlets]] and [[outlets]] (sphcore/open_boundary.py): boxes of the scene's dimension, along
    one axis, at least a support radius thick along it (the fluid beside them needs its whole
    support: a thinner zone leaves the nearest fluid short of neighbours), not overlapping each
    other, with the weakly compressible solver."""
    zones = [("inlets", i, z) for i, z in enumerate(s.inlets)] + [("outlets", i, z) for i, z in enumerate(s.outlets)]
    if not zones:
        return
    H = s.sph.support * s.particles.spacing
    boxes = []
    for name, i, z in zones:
        key = f"{name}[{i}]"
        _check_zone_box(s, key, z)
        vec_key, vec = (f"{key}.velocity", z.velocity) if name == "inlets" else (f"{key}.direction", z.direction)
        axis = _axis_of(s, vec_key, vec)
        if name == "outlets" and abs(vec[axis]) != 1.0:
            raise SceneError(f"{vec_key} = {list(vec[: s.dim])!r}: must be a unit vector along one axis, e.g. [1, 0"
                             f"{', 0' if s.dim == 3 else ''}]")
        if name == "inlets" and abs(vec[axis]) >= 0.1 * s.sph.sound_speed:
            raise SceneError(f"{vec_key} = {list(vec[: s.dim])!r}: at least 0.1 x sph.sound_speed = "
                             f"{0.1 * s.sph.sound_speed:g} m/s; a weakly compressible fluid needs flows 10 x slower "
                             "than sound (raise sph.sound_speed)")
        thick = z.max[axis] - z.min[axis]
        if thick < H * (1 - 1e-9):
            raise SceneError(f"{key}: {thick:g} m thick along {'xyz'[axis]}, less than the support radius "
                             f"sph.support x particles.spacing = {H:g} m (the fluid beside it would miss neighbours)")
        for other_key, lo, hi in boxes:
            if all(z.min[d] < hi[d] and lo[d] < z.max[d] for d in range(s.dim)):
                raise SceneError(f"{key}: overlaps {other_key}")
        boxes.append((key, z.min, z.max))
        _check_open_edge(s, key, name, vec_key, vec, axis, z)
    if s.sph.solver != "wcsph":
        raise SceneError(f"{zones[0][0]}[{zones[0][1]}]: inlets and outlets need sph.solver = 'wcsph' (DFSPH's "
                         "solves do not impose the zones' velocities)")


def _check_open_edge(s: Scene, key: str, name: str, vec_key: str, vec, axis: int, z):
    """An inlet's upstream face, an outlet's downstream face, lies on an open edge of the domain: on
    the domain box's face along its axis, the flow pointing in (an inlet) or out (an outlet), and no
    wall there. An outlet pointing into the domain or placed mid-channel removed the fluid (2,280 of
    2,400 particles in 2 steps), an inlet mid-channel compressed it (hostile-input sweep, 2026-12-06)."""
    lo, hi = _domain_box(s)
    slack = 1e-9 * max(_domain_extent(s)[: s.dim])
    inward = vec[axis] > 0.0  # an inlet's flow and an outlet's direction both point along +axis
    if name == "inlets":
        face, edge = (z.min[axis], lo[axis]) if inward else (z.max[axis], hi[axis])
        which = "upstream"
    else:
        face, edge = (z.max[axis], hi[axis]) if inward else (z.min[axis], lo[axis])
        which = "downstream"
    ax = "xyz"[axis]
    if abs(face - edge) > slack:
        raise SceneError(f"{key}: its {which} face ({ax} = {face:g} m, from {vec_key} = {list(vec[: s.dim])!r}) must "
                         f"lie on the domain's edge at {ax} = {edge:g} m, where the flow "
                         f"{'enters' if name == 'inlets' else 'leaves'}")
    walled = s.domain.container != "none" or s.domain.periodic[axis] or any(
        abs(pl.normal[axis]) > 0.0 and all(pl.normal[d] == 0.0 for d in range(s.dim) if d != axis)
        and abs(pl.point[axis] - face) <= slack for pl in s.domain.planes)
    if walled:
        raise SceneError(f"{key}: its {which} face at {ax} = {face:g} m is a wall or a periodic edge, not an open one "
                         "(inlets and outlets need domain.container = 'none', no plane on that face and no "
                         f"periodic {ax})")


def _domain_box(s: Scene) -> tuple[list, list]:
    """The domain's axis-aligned box (lo, hi), in the run's coordinates (m)."""
    dom = s.domain
    if dom.container == "none":
        return list(dom.bounds_min), list(dom.bounds_max)
    half = [0.5 * e for e in _domain_extent(s)]
    return [c - h for c, h in zip(dom.center, half)], [c + h for c, h in zip(dom.center, half)]


def _check_zone_box(s: Scene, key: str, z):
    """A zone's box (an inlet's, an outlet's, a damping zone's: its ``min`` and ``max``): of the
    scene's dimension, not empty on any axis, inside the domain's box."""
    lo, hi = _domain_box(s)
    slack = 1e-9 * max(_domain_extent(s)[: s.dim])
    if s.dim == 2 and (z.min[2] or z.max[2]):
        raise SceneError(f"{key}: min and max z must be 0 in a 2D scene")
    if any(z.max[d] <= z.min[d] for d in range(s.dim)):
        raise SceneError(f"{key}.max = {list(z.max[: s.dim])!r}: must exceed {key}.min = {list(z.min[: s.dim])!r} "
                         "on every axis")
    if any(z.min[d] < lo[d] - slack or z.max[d] > hi[d] + slack for d in range(s.dim)):
        raise SceneError(f"{key}: the zone {list(z.min[: s.dim])!r} .. {list(z.max[: s.dim])!r} reaches outside the "
                         f"domain's box {[round(v, 12) for v in lo[: s.dim]]!r} .. "
                         f"{[round(v, 12) for v in hi[: s.dim]]!r}")


def _check_damping_zones(s: Scene):
    """[[damping_zones]] (physics/damping.py): boxes of the scene's dimension inside the domain's
    box, a direction along one axis, and a rate the largest step integrates stably (v (1 - k dt)
    must not turn v around: rate x time.dt < 1)."""
    if not s.damping_zones:
        return
    for i, z in enumerate(s.damping_zones):
        key = f"damping_zones[{i}]"
        _check_zone_box(s, key, z)
        axis = _axis_of(s, f"{key}.direction", z.direction)
        if abs(z.direction[axis]) != 1.0:
            raise SceneError(f"{key}.direction = {list(z.direction[: s.dim])!r}: must be a unit vector along one axis, "
                             f"e.g. [1, 0{', 0' if s.dim == 3 else ''}]")
        if z.rate * s.time.dt >= 1.0:
            raise SceneError(f"{key}.rate = {z.rate!r}: rate x time.dt = {z.rate * s.time.dt:g} must be below 1 (the "
                             f"largest step, time.dt = {s.time.dt:g} s, would turn the velocity around); lower the "
                             "rate or time.dt")


def _check_probes(s: Scene):
    """Probe names (a CSV column, a Rerun entity path), unique; a height probe needs gravity to know
    which way is up. Whether each point lies inside the domain needs the walls: sphcore/probes.py
    ``check_inside``, before the first step."""
    seen = {}
    for i, probe in enumerate(s.probes):
        key = f"probes[{i}]"
        if not PROBE_NAME.fullmatch(probe.name):
            raise SceneError(f"{key}.name = {_short(probe.name)}: allowed are a letter, then letters, digits, _ . or - "
                             "(at most 64 characters: it is a column of probes.csv and the Rerun entity probes/<name>)")
        if probe.name in ("step", "t"):
            raise SceneError(f"{key}.name = {probe.name!r}: 'step' and 't' are probes.csv's first columns; choose "
                             "another name")
        if probe.name in seen:
            raise SceneError(f"{key}.name = {probe.name!r}: already the name of probes[{seen[probe.name]}]; probe "
                             "names must be unique")
        seen[probe.name] = i
        if s.dim == 2 and probe.at[2] != 0.0:
            raise SceneError(f"{key}.at = {list(probe.at)!r}: z must be 0 in 2D (the particles lie in z = 0)")
        if probe.kind == "pressure" and probe.gauge != "highest":
            raise SceneError(f"{key}.gauge = {probe.gauge!r}: a pressure probe has no gauge; gauge is a height "
                             "probe's (kind = 'height')")
        if probe.kind == "height" and not any(s.forces.gravity):
            raise SceneError(f"{key}.kind = 'height': needs forces.gravity (the vertical is the direction opposite "
                             f"gravity), but forces.gravity = {list(s.forces.gravity[: s.dim])!r}")


# Memory of one process, per particle and per grid cell, at float64 (f32 needs less): the state
# (id, x, v, m, a, rho, p: 104 B), its copy while the grid sorts it, the sort keys, the stages'
# scratch and the temporaries of generating the lattice and gathering final.npz; the grid holds
# three int64 arrays per cell (bin starts, cell begin and end). Measured: the peak RSS of the 3D dam
# break grows by 540 B per particle from 49,152 to 224,720 particles (WCSPH, f64, 3 steps); Python
# and the libraries add about 260 MB whatever the scene. An estimate, on the high side (docs/USAGE.md
# "sph scene" gives a command that measures it: 476 B per particle when only stepping).
BYTES_PER_PARTICLE = 600
BYTES_PER_CELL = 32
# The host's share when the particles live on a GPU (--backend cuda): generating the lattice (float64
# x and v) and the host mirror of the state. Measured: the peak RSS of setting up the 3D dam break at
# 10 M particles grows by 108 B per particle in float32 and 80 B in float64 (scripts/bench_setup.py).
HOST_BYTES_PER_PARTICLE = {"cpu": BYTES_PER_PARTICLE, "cuda": 160}
# DFSPH on the CPU with lists stores m_j grad W_ij per list entry (model.pair_gradients): 3 float64 per
# entry of the default list capacity (64 + a spare column).
PAIR_GRADIENT_BYTES = 3 * 65 * 8


def grid_reach(s: Scene) -> int:
    """Grid cells per support radius (run.cells_per_support; 0: 2 with lists, 1 with the walk). Cells
    of H / 2 halve the candidates of the list build, once a step; a walk visits its cells in every
    pass, and 5^3 of them cost it more than they save (docs/BENCHMARKS.md, "Grid cells of H / 2")."""
    if s.run.cells_per_support:
        return s.run.cells_per_support
    return 2 if s.run.neighbours == "lists" else 1


def pressure_scale(s: Scene, length: float) -> float:
    """Pa: the largest pressure the scene can hold, the scale of the integer quanta its exact sums
    count in (probes.py, the traction's moments): rho0 c0^2 (the equation of state's stiffness),
    or rho0 |g| L for a column ``length`` deep if that is more, and never under 1 Pa."""
    rho0, c0 = s.fluid.rest_density, s.sph.sound_speed
    g = float(np.linalg.norm(np.add(s.forces.gravity, s.forces.external)))
    return max(rho0 * c0 * c0, rho0 * g * length, 1.0)


def stores_pair_gradients(s: Scene, backend: str = "cpu") -> bool:
    """Whether a run stores m_j grad W_ij per list entry (model.pair_gradients): DFSPH, lists, the CPU."""
    return s.sph.solver == "dfsph" and s.run.neighbours == "lists" and backend == "cpu"


def bytes_per_particle(s: Scene, backend: str = "cpu") -> int:
    """The host memory estimate per particle of one process (HOST_BYTES_PER_PARTICLE; with DFSPH's
    stored pair gradients when the scene has them)."""
    return (HOST_BYTES_PER_PARTICLE[backend] + (PAIR_GRADIENT_BYTES if stores_pair_gradients(s, backend) else 0)
            + skin_bytes(s, backend))


# run.neighbour_skin = -1, by solver, where a reuse pays (docs/BENCHMARKS.md, "Verlet lists"): WCSPH 0.2,
# which beat 0.1 on the developed dam break; DFSPH 0.45: its steps move the fastest particles ~0.2
# spacings (the displacement limit), so a build comes every ~3 steps (0.3: every 2nd; 0.6: the larger
# candidate lists cost more than they save): 51.5 against 54.6 ms a step to t = 0.5 s at 49k, 2 threads
AUTO_SKIN = {"wcsph": 0.2, "dfsph": 0.45}


def _period(s: Scene, d: int) -> float:
    """The length of periodic axis d (m)."""
    dom = s.domain
    return dom.size[d] if dom.container == "box" else dom.bounds_max[d] - dom.bounds_min[d]


def list_skin(s: Scene, backend: str = "cpu") -> float:
    """The run's list skin (run.neighbour_skin, -1 resolved): the solver's AUTO_SKIN with lists on the
    CPU backend, else 0 (the GPU and the cell walk have no skin); 0 too where a periodic axis is shorter
    than 3 H (1 + skin) (the lists' cells must tile the period)."""
    if s.run.neighbour_skin >= 0.0:
        return s.run.neighbour_skin
    if not (s.run.neighbours == "lists" and backend == "cpu"):
        return 0.0
    skin = AUTO_SKIN[s.sph.solver]
    H = s.sph.support * s.particles.spacing
    if any(s.domain.periodic[d] and _period(s, d) < 3.0 * H * (1.0 + skin) for d in range(s.dim)):
        return 0.0
    return skin


def skin_bytes(s: Scene, backend: str = "cpu") -> int:
    """Per particle, what reused lists add (run.neighbour_skin): the candidate lists (int32: the
    default list capacity of 64 grown by (1 + skin)^dim, with the builder's 25 % + 8 of headroom and
    its spare column) and the reference positions (3 x 8 B at most). Measured: 513 B a particle more
    at a skin of 0.2 on the 3D dam break at 197,676 particles, float32, its flow developed
    (docs/BENCHMARKS.md); this gives 612."""
    skin = list_skin(s, backend)
    if not skin:
        return 0
    return int(4 * (1.25 * 64 * (1.0 + skin) ** s.dim + 9)) + 24


def block_estimate(block: Block, dim: int, dx: float) -> float:
    """About how many lattice points ``block`` fills (before anything outside the domain or inside an
    obstacle is carved away); inf where that overflows, for a tiny spacing or a huge block (products,
    not ``**``, which raises on overflow; the caller refuses more than particles.max_particles)."""
    if block.shape == "box":
        return float(math.prod(max((block.max[d] - block.min[d]) / dx, 1.0) for d in range(dim)))
    r = block.radius / dx  # the radius in spacings
    return math.pi * r * r if dim == 2 else 4.0 / 3.0 * math.pi * r * r * r


def _domain_extent(s: Scene) -> list[float]:
    """The edge lengths of the domain's bounding box (an upper bound for a rotated container)."""
    dom = s.domain
    if dom.container == "none":
        return [dom.bounds_max[d] - dom.bounds_min[d] for d in range(3)]
    if dom.container == "box":
        edges = [e * dom.scale for e in dom.size]
    elif dom.container == "sphere":
        edges = [2.0 * dom.radius * dom.scale] * 3
    else:
        edges = [dom.size[0] * dom.scale, dom.size[1] * dom.scale, dom.size[0] * dom.scale]
    if any(dom.rotation):
        edges = [math.hypot(*edges[: s.dim])] * 3
    return edges


def available_memory() -> int | None:
    """Bytes of memory a new allocation can get on this machine (Linux MemAvailable), or None."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return None


def size_text(nbytes: float) -> str:
    """1.23 GB, 456 MB, 12 kB, 80 B."""
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if nbytes >= scale:
            return f"{nbytes / scale:.3g} {unit}"
    return f"{int(nbytes)} B"


def resource_estimate(s: Scene, backend: str = "cpu") -> dict:
    """What the scene needs before any array exists: particles (lattice estimate, per block and in
    all), grid cells and the host memory of one process (bytes; HOST_BYTES_PER_PARTICLE of the
    backend)."""
    dx = s.particles.spacing
    per_block = [block_estimate(b, s.dim, dx) for b in s.fluid.blocks]
    particles = sum(per_block)
    H = s.sph.support * dx
    cells = math.prod(max(e, 0.0) * grid_reach(s) / H + 3.0 for e in _domain_extent(s)[: s.dim])
    return {"per_block": per_block, "particles": particles, "cells": cells,
            "memory": particles * bytes_per_particle(s, backend) + cells * BYTES_PER_CELL}


def _check_resources(s: Scene, available: int | None = None, backend: str = "cpu"):
    """Refuse a scene that would make more particles than particles.max_particles, or need more memory
    than this machine has free, before anything is allocated."""
    dx = s.particles.spacing
    extent = _domain_extent(s)[: s.dim]
    if not dx < min(extent):  # (the kernel's constants overflowed at 1e300 m)
        raise SceneError(f"particles.spacing = {dx!r}: not smaller than the domain, whose shortest edge is "
                         f"{min(extent):.4g} m")
    est = resource_estimate(s, backend)
    limit = s.particles.max_particles
    if est["particles"] > limit:
        raise SceneError(f"particles.spacing = {dx!r}: would create about {est['particles']:.3g} particles, more "
                         f"than particles.max_particles = {limit} (raise the spacing or the limit)")
    available = available_memory() if available is None else available
    if available is not None and est["memory"] > available:
        raise SceneError(f"particles.spacing = {dx!r}: about {est['particles']:.3g} particles and {est['cells']:.3g} "
                         f"grid cells need about {size_text(est['memory'])} of memory ({bytes_per_particle(s, backend)} B per "
                         f"particle, {BYTES_PER_CELL} B per cell), more than the {size_text(available)} available "
                         "here; raise particles.spacing or make the blocks or the domain smaller")


def reference_markdown() -> str:
    """Markdown tables of every scene key (section, key, default, allowed, meaning), generated from
    the declarations above; docs/USAGE.md embeds it and a test keeps the two equal."""
    lines = []
    tables = [(name, cls) for name, cls in SECTIONS.items() if name != "obstacles"]
    tables.insert(tables.index(("domain", Domain)) + 1, ("obstacles", Obstacle))
    for path, cls in tables + [("fluid.blocks", Block), ("domain.planes", Plane)]:
        header = f"[[{path}]]" if path in LIST_ITEMS else f"[{path}]"
        lines += [f"#### `{header}`", "", "| key | default | allowed | meaning |", "|---|---|---|---|"]
        for f in dataclasses.fields(cls):
            if f"{path}.{f.name}" in LIST_ITEMS:
                continue
            meta = f.metadata
            default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
            allowed = ""
            if meta.get("choices"):
                allowed = ", ".join(f"`{c}`" for c in meta["choices"])
            elif meta.get("range"):
                lo, hi = meta["range"]
                allowed = f"{'(' if meta.get('min_exclusive') else '['}{lo:g}, {hi:g}]"
            elif meta.get("length"):
                allowed = " or ".join(map(str, meta["length"])) + " components"
            shown = _toml_value(default)
            lines.append(f"| `{f.name}` | `{shown}` | {allowed} | {meta['help']} |")
        lines.append("")
    return "\n".join(lines)


def _field_of(path: list, text: str) -> tuple[str, dataclasses.Field, str]:
    """(key, its declaration, the section or array-of-tables path it is declared in) of an override
    path (``parse_override``); SceneError naming an unknown section or key."""
    if len(path) < 2 or not isinstance(path[0], str):
        raise SceneError(f"{text!r}: expected section.key=value")
    if path[0] not in SECTIONS:
        raise SceneError(f"{text!r}: unknown section '{path[0]}'{_did_you_mean(path[0], SECTIONS)} "
                         f"(sections: {', '.join(SECTIONS)})")
    for i, seg in enumerate(path):  # an index follows an array of tables ([[fluid.blocks]], [[obstacles]])
        before = ".".join(s for s in path[:i] if isinstance(s, str))
        if isinstance(seg, int) and (before not in LIST_ITEMS or isinstance(path[i - 1], int)):
            raise SceneError(f"{text!r}: [{seg}] after {before!r}, which is not an array of tables")
    cls, where, names = SECTIONS[path[0]], path[0], [p for p in path if isinstance(p, str)]
    for name in names[1:-1]:
        if f"{where}.{name}" not in LIST_ITEMS:
            raise SceneError(f"{text!r}: [{where}] has no array of tables {name!r}")
        where = f"{where}.{name}"
        cls = LIST_ITEMS[where]
    fields = {f.name: f for f in dataclasses.fields(cls)}
    name = names[-1]
    if name not in fields:
        raise SceneError(f"{text!r}: unknown key '{where}.{name}'{_did_you_mean(name, fields)} (allowed in "
                         f"[{where}]: {', '.join(fields)})")
    return f"{where}.{name}", fields[name], where


def key_control(key: str):
    """LIVE if scene key ``key`` ("section.name", or an item of an array of tables such as
    "fluid.blocks[0].velocity") may change while the run goes on, else the reason it may not
    (a phrase: "changes the compiled step ..."); SceneError for a key that does not exist."""
    path, _ = parse_override(f"{key}=0")
    key, f, where = _field_of(path, key)
    if any(isinstance(p, int) for p in path) or where in LIST_ITEMS or where == "obstacles":
        return f.metadata.get("control") or SECTION_CONTROL[where if where in SECTION_CONTROL else path[0]]
    control = f.metadata.get("control")
    return control if control is not None else SECTION_CONTROL[where]


def live_keys() -> list[str]:
    """Every scene key that may change while a run goes on, in declaration order."""
    return [f"{name}.{f.name}" for name, cls in SECTIONS.items() if name != "obstacles"
            for f in dataclasses.fields(cls) if f"{name}.{f.name}" not in LIST_ITEMS
            and key_control(f"{name}.{f.name}") is LIVE]


def live_change(scene: Scene, text: str) -> tuple[str, Scene]:
    """``KEY=VALUE`` (``--set`` syntax) applied to ``scene`` for a key that may change while the run
    goes on: (the key, the new scene), the value checked like the scene file (type, range, the
    cross-key rules). SceneError naming the key, the value and what is allowed, or why the key
    cannot change during a run."""
    path, value = parse_override(text)
    key, f, where = _field_of(path, text)
    control = key_control(".".join(str(p) if isinstance(p, str) else f"[{p}]" for p in path).replace(".[", "["))
    if control is not LIVE:
        raise SceneError(f"{key} cannot change during a run: it {control} (keys that can: {', '.join(live_keys())})")
    checked = _check_value(key, f, value)
    if f.metadata.get("length") == VEC and len(checked) == 2:
        if scene.dim == 3:
            raise SceneError(f"{key} = {list(checked)!r}: a 3D scene needs 3 components")
        checked = _pad(checked)
    if f.metadata.get("position"):  # given in world coordinates, held relative to the run's origin
        checked = tuple(c - o for c, o in zip(checked, scene.origin))
    section = getattr(scene, where)
    if getattr(section, f.name) == checked:
        return key, scene
    new = dataclasses.replace(scene, **{where: dataclasses.replace(section, **{f.name: checked})})
    return key, _check_combinations(new, files=False)


def control_markdown() -> str:
    """Markdown of which scene keys may change during a run (``sph control OUT set KEY=VALUE``) and
    why the others may not, generated from the declarations above; docs/USAGE.md embeds it."""
    lines = ["| key | meaning |", "|---|---|"]
    for key in live_keys():
        section, name = key.split(".")
        f = next(f for f in dataclasses.fields(SECTIONS[section]) if f.name == name)
        lines.append(f"| `{key}` | {f.metadata['help'].replace('|', chr(92) + '|')} |")
    fixed = {}
    for name, cls in list(SECTIONS.items()) + list(LIST_ITEMS.items()):
        if name == "obstacles" and cls is Obstacle and name in fixed.get(WORLD, []):
            continue
        for f in dataclasses.fields(cls):
            key = f"{name}.{f.name}" if name not in LIST_ITEMS else f"{name}[].{f.name}"
            if f"{name}.{f.name}" in LIST_ITEMS or key in fixed.get(WORLD, []):
                continue
            control = key_control(key.replace("[]", "[0]"))
            if control is not LIVE:
                fixed.setdefault(control, [])
                if key not in fixed[control]:
                    fixed[control].append(key)
    lines += ["", "Not during a run (each refusal names its reason):", ""]
    for reason, keys in fixed.items():
        lines.append(f"- {', '.join(f'`{k}`' for k in keys)}: {reason}.")
    return "\n".join(lines)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, (tuple, list)):
        return "[" + ", ".join(_toml_value(e) for e in v) + "]"
    return f"{v:g}" if isinstance(v, float) else str(v)


def scene_toml(resolved: dict) -> str:
    """TOML text of a resolved scene (Scene.to_dict): one line per key, vectors on one line, each
    array of tables as [[section.key]] after its section's keys."""
    lines = []

    def table(path: str, values: dict, header: str):
        lines.append(header)
        nested = []
        for key, value in values.items():
            if isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
                nested.append((key, value))
            elif isinstance(value, list) and not value and f"{path}.{key}" in LIST_ITEMS:
                continue  # an empty array of tables: nothing to write
            else:
                lines.append(f"{key} = {_toml_exact(value)}")
        lines.append("")
        for key, items in nested:
            for item in items:
                table(f"{path}.{key}", item, f"[[{path}.{key}]]")

    for name, value in resolved.items():
        if isinstance(value, list):
            for item in value:
                table(name, item, f"[[{name}]]")
        else:
            table(name, value, f"[{name}]")
    return "\n".join(lines)


def _toml_exact(v) -> str:
    """A TOML value that reads back to exactly ``v`` (floats by repr, not rounded like _toml_value)."""
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, str):  # JSON's escapes are TOML's; DEL is the one control character JSON leaves raw
        return json.dumps(v).replace("\x7f", "\\u007f")
    if isinstance(v, (tuple, list)):
        return "[" + ", ".join(_toml_exact(e) for e in v) + "]"
    return _toml_value(v)
