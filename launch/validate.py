"""``sph validate``: run validation cases against reference data; one line per metric, a plot per
case, exit code 1 if any metric fails.

    sph validate CASE [--quick] [--out DIR]      CASE: hydrostatic, hydrostatic_3d, dam_break, dam_break_3d,
                                                       taylor_green, oscillating_drop, poiseuille, couette,
                                                       floating_box, floating_square, settling_cylinder,
                                                       settling_cylinder_closed,
                                                       hydrostatic_probes,
                                                       cavity, dam_break_pressure, channel, circular_couette,
                                                       wave_maker, dam_break_obstacle
    sph validate --all [--quick]
    sph validate CASE --orders K                 the case in K orders of the same sums: each metric's mean
                                                 and spread (run_orders)

Each case is a function of (quick, out folder) returning its metrics; ``--quick`` uses a coarser
resolution so each case takes a few minutes at most on 2 cores (the 3D dam_break_obstacle about 4).
Tolerances are the issue's targets; a metric that misses its tolerance is reported FAIL, never
loosened to pass.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sphcore.scene import SceneError, grid_reach, list_skin, load_scene
from sphcore.solver import Simulation

log = logging.getLogger("sph.validate")
CONFIGS = Path(__file__).resolve().parent.parent / "configs"

# Martin & Moyce (1952), n^2 = 2, a = 2.25 in: surge front Z = x/a against T = t sqrt(2 g / a)
MARTIN_MOYCE_T = np.array([0.832, 1.219, 1.997, 2.547, 3.345, 4.034, 4.418, 5.091, 5.685, 6.306, 6.822, 7.439,
                           8.031, 8.633, 9.237])
MARTIN_MOYCE_Z = np.array([1.217, 1.474, 2.292, 2.995, 4.134, 4.944, 5.881, 6.980, 7.945, 8.966, 9.986, 10.963,
                           11.977, 13.005, 13.970])
MARTIN_MOYCE_A = 2.25 * 0.0254  # m: the experiment's column width

# Ghia, Ghia & Shin (1982), "High-Re solutions for incompressible flow using the Navier-Stokes
# equations and a multigrid method", J. Comput. Phys. 48:387-411, lid-driven cavity, Re = 100 columns
# (129 x 129 grid): Table I, u / U along the vertical centreline x = 0.5 at the heights y / L;
# Table II, v / U along the horizontal centreline y = 0.5 at the abscissae x / L. The first and last
# rows are the walls (the lid moves at U along x).
GHIA_Y = np.array([1.0000, 0.9766, 0.9688, 0.9609, 0.9531, 0.8516, 0.7344, 0.6172, 0.5000, 0.4531, 0.2813,
                   0.1719, 0.1016, 0.0703, 0.0625, 0.0547, 0.0000])
GHIA_U_RE100 = np.array([1.00000, 0.84123, 0.78871, 0.73722, 0.68717, 0.23151, 0.00332, -0.13641, -0.20581,
                         -0.21090, -0.15662, -0.10150, -0.06434, -0.04775, -0.04192, -0.03717, 0.00000])
GHIA_X = np.array([1.0000, 0.9688, 0.9609, 0.9531, 0.9453, 0.9063, 0.8594, 0.8047, 0.5000, 0.2344, 0.2266,
                   0.1563, 0.0938, 0.0781, 0.0703, 0.0625, 0.0000])
GHIA_V_RE100 = np.array([0.00000, -0.05906, -0.07391, -0.08864, -0.10313, -0.16914, -0.22445, -0.24533, 0.05454,
                         0.17527, 0.17507, 0.16077, 0.12317, 0.10890, 0.10091, 0.09233, 0.00000])


@dataclass
class Metric:
    """One verdict: ``value`` against ``tolerance`` (PASS if value <= tolerance). A relative metric,
    |quantity / reference - 1|, may give its ``quantity`` and ``reference``: over several orders of the
    sums (run_orders) it is then the mean quantity that is compared, not the mean of the errors."""
    name: str
    value: float
    tolerance: float
    note: str = ""
    quantity: float = float("nan")
    reference: float = float("nan")

    @property
    def passed(self) -> bool:
        return bool(np.isfinite(self.value) and self.value <= self.tolerance)

    def line(self) -> str:
        return (f"{self.name:<34} {self.value:10.4g} {self.tolerance:10.4g} {'PASS' if self.passed else 'FAIL'}"
                + (f"   ({self.note})" if self.note else ""))


@dataclass
class CaseOptions:
    """How to run a case: ``sph validate`` uses the defaults; ``sph study`` varies them. ``dx`` None
    means the case's own (quick or full) spacing; ``overrides`` are --set strings; after the run
    ``stats`` holds particles, steps, sim_time and wall_s (stepping only, the first step excluded:
    it compiles or loads numba's cache)."""
    backend: str = "cpu"
    precision: str = "f64"
    dx: float | None = None
    overrides: tuple = ()
    plot: bool = True
    stats: dict = field(default_factory=dict)
    orders_run: dict = field(default_factory=dict)  # run_orders: the sums already run, (skin, cells per H) -> label

    def check_order(self, resolved: tuple):
        """Record the run's order of the sums, (list skin, grid cells per support); RepeatedOrder if
        ``orders_run`` holds it already (run_orders: the same sums twice would fake an agreement)."""
        self.stats["sums_order"] = resolved
        if resolved in self.orders_run:
            raise RepeatedOrder(f"the same sums as {self.orders_run[resolved]} here")


class RepeatedOrder(Exception):
    """A run of run_orders whose sums, resolved by its scene and backend, one already ran."""


class _Clock:
    """Wall time of the stepping loop from the end of the first step; a progress line every
    PROGRESS_S seconds (a full 3D case runs for tens of minutes)."""
    PROGRESS_S = 30.0

    def __init__(self, sim, opts: CaseOptions, name: str, t_end: float):
        self.sim, self.opts, self.name, self.t_end, self.t0 = sim, opts, name, t_end, None
        opts.check_order((list_skin(sim.scene, opts.backend), grid_reach(sim.scene)))  # before any step

    def tick(self):
        sim = self.sim
        if self.t0 is None and sim.step_index >= 1:
            self.t0 = self.shown = time.perf_counter()
            self.steps0, self.time0 = sim.step_index, sim.t
        elif self.t0 is not None and time.perf_counter() - self.shown > self.PROGRESS_S:
            self.shown = now = time.perf_counter()
            rate = (sim.t - self.time0) / (now - self.t0)  # simulated s per wall s
            left = (self.t_end - sim.t) / rate if rate > 0.0 else float("inf")
            log.info("%s: t = %.3g of %.3g s, step %d, %d particles, about %.0f s left", self.name, sim.t,
                     self.t_end, sim.step_index, sim.n_particles, left)

    def done(self):
        wall = time.perf_counter() - self.t0 if self.t0 is not None else float("nan")
        sim = self.sim
        self.opts.stats.update(particles=sim.n_particles, steps=sim.step_index - self.steps0,
                               sim_time=sim.t - self.time0, wall_s=wall)
        if sim.dfsph:  # iterations per step of the incompressible solver's two solves
            for name, st in sim.solver_stats.items():
                self.opts.stats[f"{name}_iterations"] = st["iterations"] / max(st["steps"], 1)
                self.opts.stats[f"{name}_unconverged"] = st["unconverged"]


def _sampled(sim, clock, t_end: float, every: int):
    """Step ``sim`` to ``t_end`` (its last step shortened to land there), yielding after every
    ``every``-th step and after the last: where a case samples its run."""
    while sim.t < t_end:
        sim.step(dt_cap=t_end - sim.t)
        clock.tick()
        if sim.step_index % every == 0 or sim.t >= t_end:
            yield


def _plot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


# the 2D dam break extruded WIDTH_3D in z, periodic across: the same flow in 3D (no side walls, so
# no side-wall friction the 2D flow has not; 0.07 m is 3 support radii at the quick spacing, the
# least a periodic axis takes)
WIDTH_3D = 0.07
DAM_BREAK_3D = ("scene.dim=3", "fluid.blocks[0].min=[0,0,0]", f"fluid.blocks[0].max=[0.2,0.4,{WIDTH_3D}]",
                f"domain.center=[0.8,0.3,{WIDTH_3D / 2}]", f"domain.size=[1.6,0.6,{WIDTH_3D}]",
                "domain.periodic=[false,false,true]", "forces.gravity=[0,-9.81,0]", "forces.external=[0,0,0]")

# The tank's walls rub: the dam-break cases run with the turbulent wall friction of a smooth wall
# (terms.wall_friction, sphcore/physics/wall_friction.py) at the experiment's Reynolds number. The
# scene's column (a = 0.2 m) is 3.5 times the experiment's (2.25 in), and Froude similarity scales
# velocities by sqrt(a); the same Reynolds number U a / nu then takes water's nu (1.0e-6 m^2/s at
# about 20 C) times (a / a_exp)^(3/2). Nothing in it is fitted to the front.
WATER_NU = 1.0e-6


def martin_moyce_nu(a: float) -> float:
    """The kinematic viscosity (m^2/s) at which a column a wide has Martin & Moyce's Reynolds number."""
    return WATER_NU * (a / MARTIN_MOYCE_A) ** 1.5


# The experiment's clock starts at the release of the column, which is not instantaneous: the
# simulated front (released at once) leads Martin & Moyce's from their first point on. The
# literature's correction is one fixed shift of the simulated clock, T + MARTIN_MOYCE_SHIFT_T (the
# gate's opening, as published validation scripts apply it), the same for every run: a shift fitted
# per run would absorb a front that starts too fast or runs at the wrong speed. The metrics are the
# RMS with that shift over all 15 points (a 3 m tank lets the front reach Z = 14) and the late front's
# speed; the raw RMS and a fitted delay are printed beside them as diagnostics, never as the result.
MARTIN_MOYCE_SHIFT_T = 0.175
LONG_TANK_2D = ("domain.center=[1.5,0.3]", "domain.size=[3.0,0.6]")  # 3 m: the front reaches Z = 15
LONG_TANK_3D = (f"domain.center=[1.5,0.3,{WIDTH_3D / 2}]", f"domain.size=[3.0,0.6,{WIDTH_3D}]")
LATE = (8, 13)  # the measured points T = 5.69 and 8.63 between which the late speed dZ/dT is taken
RELEASE_DELAY_MAX_T = 0.5  # the longest delay the diagnostic fit searches is twice this
RELEASE_FIT_STEP_T = 0.001  # resolution of the fitted delay


def front_rms(t_exp, z_exp, times, fronts, delay: float = 0.0) -> float:
    """RMS over the measured points of (Z_sim - Z_exp) / Z_exp, the simulated front read at the
    experiment's T minus ``delay`` (the release time of the experiment's clock)."""
    z_sim = np.interp(np.asarray(t_exp) - delay, times, fronts)
    return float(np.sqrt(np.mean(((z_sim - z_exp) / z_exp) ** 2)))


def fit_release_delay(t_exp, z_exp, times, fronts, longest: float = 2.0 * RELEASE_DELAY_MAX_T) -> float:
    """The delay dT in [0, longest] that minimises ``front_rms`` (a diagnostic: how far the
    simulated front's start is from the experiment's): a release can only make the experiment late,
    never early. Searched on a grid of RELEASE_FIT_STEP_T (the RMS is not smooth in dT: the front is a
    staircase of particle positions)."""
    delays = np.arange(0.0, longest + 0.5 * RELEASE_FIT_STEP_T, RELEASE_FIT_STEP_T)
    errors = [front_rms(t_exp, z_exp, times, fronts, d) for d in delays]
    return float(delays[int(np.argmin(errors))])


def front_speed(t_exp, times, fronts, delay: float = MARTIN_MOYCE_SHIFT_T) -> float:
    """The simulated front's mean speed dZ/dT between the measured points LATE (read on the
    experiment's clock, like ``front_rms``)."""
    t0, t1 = t_exp[LATE[0]], t_exp[LATE[1]]
    z0, z1 = np.interp([t0 - delay, t1 - delay], times, fronts)
    return float((z1 - z0) / (t1 - t0))


def dam_break_scene(dx: float, dim: int = 2, overrides=()):
    """configs/dam_break_2d.toml at spacing dx in the 3 m tank, in 2D or extruded to 3D (its probes
    then sit on the extrusion's mid-plane), with the walls' friction at Martin & Moyce's Reynolds
    number; ``overrides`` last, so that they win (``terms.wall_friction=0``: free-slip walls)."""
    base = load_scene(CONFIGS / "dam_break_2d.toml")
    a = base.fluid.blocks[0].max[0] - base.fluid.blocks[0].min[0]
    extra = (*LONG_TANK_2D, f"terms.wall_friction={martin_moyce_nu(a)!r}")
    if dim == 3:
        extra = (*DAM_BREAK_3D, *LONG_TANK_3D, extra[-1],
                 *(f"probes[{i}].at=[{p.at[0]!r},{p.at[1]!r},{0.5 * WIDTH_3D!r}]" for i, p in enumerate(base.probes)))
    return load_scene(CONFIGS / "dam_break_2d.toml", [f"particles.spacing={dx}", *extra, *overrides])


def dam_break(quick: bool, out: Path, backend: str = "cpu", opts: CaseOptions | None = None,
              dim: int = 2) -> list[Metric]:
    """Column a wide and 2a high collapsing in a 3 m tank (2D, or 3D: extruded, periodic across), its
    walls' friction at the experiment's Reynolds number; surge front against Martin & Moyce with the
    literature's fixed release shift, and its late speed."""
    opts = opts or CaseOptions(backend)
    dx = opts.dx or (0.01 if quick else 0.005)
    scene = dam_break_scene(dx, dim, opts.overrides)
    dx = scene.particles.spacing  # an override of the spacing wins
    name = "dam_break" if dim == 2 else "dam_break_3d"
    a = scene.fluid.blocks[0].max[0] - scene.fluid.blocks[0].min[0]
    x_wall = scene.domain.center[0] + 0.5 * scene.domain.size[0]
    g = abs(scene.forces.gravity[1])
    scale = math.sqrt(2.0 * g / a)
    usable = MARTIN_MOYCE_Z < (x_wall - 2 * dx) / a  # points before the front reaches the far wall
    t_exp, z_exp = MARTIN_MOYCE_T[usable], MARTIN_MOYCE_Z[usable]
    sim = Simulation(scene, opts.precision, opts.backend)
    t_end = t_exp[-1] / scale
    clock = _Clock(sim, opts, name, t_end)
    times, fronts = [0.0], [1.0]
    while sim.t < t_end:
        sim.step(dt_cap=t_end - sim.t)
        clock.tick()
        s = sim.state
        n = s.n_owned
        low = s.x[:n, 1] < 0.25 * a  # the front runs along the floor
        times.append(sim.t * scale)
        fronts.append(float(np.max(s.x[:n, 0][low])) / a if low.any() else float("nan"))
    clock.done()
    shift = MARTIN_MOYCE_SHIFT_T
    rms = front_rms(t_exp, z_exp, times, fronts, shift)
    raw = front_rms(t_exp, z_exp, times, fronts)
    delay = fit_release_delay(t_exp, z_exp, times, fronts)
    fitted = front_rms(t_exp, z_exp, times, fronts, delay)
    metrics = [Metric(f"{name}.front_rms_shifted", rms, 0.05 if quick else 0.03,
                      f"{len(t_exp)} points, T <= {t_exp[-1]:.2f}, {sim.n_particles} particles; the simulated "
                      f"clock + {shift}; raw (no shift) {raw:.4f}; diagnostic: a fitted delay {delay:.3f} "
                      f"gives {fitted:.4f}")]
    if len(t_exp) > LATE[1]:
        measured = (z_exp[LATE[1]] - z_exp[LATE[0]]) / (t_exp[LATE[1]] - t_exp[LATE[0]])
        speed = front_speed(t_exp, times, fronts, shift)
        metrics.append(Metric(f"{name}.front_speed_relative", abs(speed / measured - 1.0), 0.03,
                              f"dZ/dT {speed:.3f} against the measured {measured:.3f}, "
                              f"T = {t_exp[LATE[0]]:.2f}-{t_exp[LATE[1]]:.2f}", quantity=speed, reference=measured))
    opts.stats.update(front_rms_raw=raw, front_delay_fitted_T=delay, front_rms_fitted=fitted,
                      front_at_points=np.interp(t_exp - shift, times, fronts).tolist(), front_T=times, front_Z=fronts,
                      front_speed=speed if len(t_exp) > LATE[1] else float("nan"))
    if not opts.plot:
        return metrics
    plt = _plot()
    fig, ax = plt.subplots(figsize=(6, 4))
    times = np.asarray(times)
    walls = (f"wall friction nu = {scene.terms.wall_friction:.3g} m$^2$/s" if scene.terms.wall_friction > 0
             else "free-slip walls")
    ax.plot(times + shift, fronts, label=f"sphfluid WCSPH {dim}D, dx = a/{a / dx:.0f}, clock + {shift}\n{walls}")
    ax.plot(times, fronts, "--", color="C0", lw=0.8, alpha=0.6, label="the same, raw (released at T = 0)")
    ax.plot(MARTIN_MOYCE_T, MARTIN_MOYCE_Z, "ko", mfc="none", label="Martin & Moyce (1952)")
    ax.set_xlabel("T = t sqrt(2g/a)")
    ax.set_ylabel("Z = x_front / a")
    ax.set_xlim(0, t_exp[-1] * 1.05)
    ax.set_ylim(0, max(z_exp) * 1.1)
    ax.legend(fontsize=8, loc="upper left")
    ax.set_title(f"{dim}D dam break: surge front (RMS {100 * rms:.1f} % shifted, {100 * raw:.1f} % raw)")
    fig.tight_layout()
    fig.savefig(out / f"{name}.png", dpi=100)
    plt.close(fig)
    return metrics


def taylor_green(quick: bool, out: Path, backend: str = "cpu", opts: CaseOptions | None = None) -> list[Metric]:
    """Periodic decaying vortex at Re = 100 against u = -e^{bt} cos 2pi x sin 2pi y, b = -8 pi^2 / Re."""
    opts = opts or CaseOptions(backend)
    dx = opts.dx or (0.01 if quick else 0.005)
    scene = load_scene(CONFIGS / "taylor_green_2d.toml", [f"particles.spacing={dx}", *opts.overrides])
    U, nu = scene.fluid.flow_speed, scene.sph.nu
    b = -8.0 * math.pi**2 * nu  # L = 1: Re = U L / nu
    t_end = 1.0
    sim = Simulation(scene, opts.precision, opts.backend)
    clock = _Clock(sim, opts, "taylor_green", t_end)
    times, vmax = [0.0], [float(np.max(np.linalg.norm(sim.state.v[:, :2], axis=1)))]
    while sim.t < t_end:
        sim.step(dt_cap=t_end - sim.t)
        clock.tick()
        times.append(sim.t)
        vmax.append(float(np.max(np.linalg.norm(sim.synchronised_velocity()[: sim.state.n_owned, :2], axis=1))))
    clock.done()
    v = sim.refresh()
    s = sim.state
    n = s.n_owned
    x, y = s.x[:n, 0], s.x[:n, 1]
    decay = math.exp(b * sim.t)
    exact = U * decay * np.hypot(np.cos(2 * np.pi * x) * np.sin(2 * np.pi * y),
                                 np.sin(2 * np.pi * x) * np.cos(2 * np.pi * y))
    speed = np.linalg.norm(v[:n, :2], axis=1)
    l1 = float(np.mean(np.abs(speed - exact)) / np.mean(exact))
    decay_err = float(abs(vmax[-1] / vmax[0] - decay) / decay)
    metrics = [Metric("taylor_green.speed_l1_relative", l1, 0.05, f"t = {sim.t:.2f} s, {sim.n_particles} particles"),
               Metric("taylor_green.decay_relative", decay_err, 0.05, "max |v| / max |v|(0) against e^{bt}")]
    if not opts.plot:
        return metrics
    plt = _plot()
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.semilogy(times, np.array(vmax) / vmax[0], label=f"sphfluid, dx = {dx}")
    tt = np.linspace(0, t_end, 100)
    ax.semilogy(tt, np.exp(b * tt), "k--", label="exp(-8 pi^2 t / Re)")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("max |v| / U")
    ax.legend()
    ax.set_title("Taylor-Green vortex, Re = 100")
    fig.tight_layout()
    fig.savefig(out / "taylor_green.png", dpi=100)
    plt.close(fig)
    return metrics


# The 3D tank: the 2D tank's water (0.5 m wide, 0.5 m deep) extruded 0.1 m between two walls
HYDROSTATIC_3D = ("scene.dim=3", "fluid.blocks[0].min=[0,0,0]", "fluid.blocks[0].max=[0.5,0.5,0.1]",
                  "domain.center=[0.25,0.35,0.05]", "domain.size=[0.5,0.7,0.1]", "forces.gravity=[0,-9.81,0]",
                  "forces.external=[0,0,0]")


SETTLE_WINDOW = 0.5  # s: the hydrostatic metrics average this last stretch of the settling run


def settle_and_average(sim, t_end: float, clock=None, samples: int = 10, window: float = SETTLE_WINDOW,
                       on_sample=None):
    """Step ``sim`` to ``t_end`` and average each particle's position, pressure and density over
    ``samples`` evenly spaced refreshes in the last ``window`` seconds: a weakly compressible tank at
    rest still carries acoustic noise (quick 3D tank: one sample's worst particle is 0.07-0.53 % of
    rho0 g H off over the last 0.5 s, the averaged worst 0.10 %; docs/VALIDATION.md,
    scripts/investigations/hydrostatic_layers.py), and the hydrostatic pressure is the steady part.

    ``on_sample(sim)`` is called after each refresh. Returns (times, kinetic energies of every step,
    (x (n, 3), p (n,), rho (n,)) in id order, mean height of the highest particle)."""
    times, ke, sums, tops = [], [], None, []
    for k in range(samples):
        t_mark = t_end - window + (window / samples) * (k + 1)
        while sim.t < t_mark:
            sim.step(dt_cap=t_mark - sim.t)
            if clock is not None:
                clock.tick()
            times.append(sim.t)
            ke.append(sim.kinetic_energy())
        sim.refresh()
        if on_sample is not None:
            on_sample(sim)
        s = sim.state
        n = s.n_owned
        order = np.argsort(s.id[:n], kind="stable")
        fields = (s.x[:n][order].astype(np.float64), s.p[:n][order].astype(np.float64),
                  s.rho[:n][order].astype(np.float64))
        sums = fields if sums is None else tuple(a + b for a, b in zip(sums, fields))
        tops.append(float(np.max(s.x[:n, 1])))
    if clock is not None:
        clock.done()
    return times, ke, tuple(a / samples for a in sums), float(np.mean(tops))


def depth_layers(y, H: float, dx: float, layers: int = 10):
    """Index 0..layers-1 of the equal depth layer each height y falls in, from the floor (y = 0) to
    three spacings under the surface H (the surface layer, whose support is cut, is left out: -1 below
    the floor, ``layers`` above)."""
    return np.digitize(y, np.linspace(0.0, H - 3 * dx, layers + 1)) - 1


def hydrostatic(quick: bool, out: Path, backend: str = "cpu", opts: CaseOptions | None = None,
                dim: int = 2) -> list[Metric]:
    """Still water settling in a tank (2D, or 3D: extruded between two walls): pressure against
    rho0 g (H - y) once at rest, and the decay of the spurious kinetic energy."""
    opts = opts or CaseOptions(backend)
    dx = opts.dx or (0.02 if quick else 0.01)
    extra = HYDROSTATIC_3D if dim == 3 else ()
    scene = load_scene(CONFIGS / "hydrostatic_2d.toml", [f"particles.spacing={dx}", *extra, *opts.overrides])
    name = "hydrostatic" if dim == 2 else "hydrostatic_3d"
    rho0, g = scene.fluid.rest_density, abs(scene.forces.gravity[1])
    sim = Simulation(scene, opts.precision, opts.backend)
    # the initial square lattice reorganises under pressure: the kinetic energy grows after the ramp,
    # peaks near 1.5 s (2D) or 1.3 s (3D) and then decays, more slowly in 3D (quick resolution, mean
    # of the last 0.5 s against the peak: 2D 0.03 at 3 s; 3D 0.045 at 4 s, and 0.15 when a
    # development version of this case stopped at 3 s, above the 0.1 target)
    t_end = 3.0 if dim == 2 else 4.0
    clock = _Clock(sim, opts, name, t_end)
    times, ke, (x, p, rho), top = settle_and_average(sim, t_end, clock)
    y = x[:, 1]
    H = top + 0.5 * dx  # free surface: half a spacing above the top particles
    interior = y < H - 3 * dx        # below the surface layer, whose support is cut
    ref = rho0 * g * (H - y)
    err = float(np.max(np.abs(p[interior] - ref[interior])) / (rho0 * g * H))
    dev = float(np.max(np.abs(rho[interior] / rho0 - 1.0)))
    which = depth_layers(y, H, dx)  # the depth profile: mean pressure in 10 layers
    profile = max(abs(float(np.mean(p[which == k]) - np.mean(ref[which == k]))) for k in range(10)
                  if np.any(which == k)) / (rho0 * g * H)
    # spurious motion must die out, not persist: the mean kinetic energy of the averaging window
    # against its peak (the lattice's reorganisation after the gravity ramp)
    times, ke = np.asarray(times), np.asarray(ke)
    peak = float(np.max(ke))
    decay = float(np.mean(ke[times > t_end - SETTLE_WINDOW])) / peak if peak > 0.0 else 0.0
    metrics = [Metric(f"{name}.pressure_error_of_rho_g_H", err, 0.01,
                      f"max over {int(interior.sum())} particles, each averaged over the last {SETTLE_WINDOW:g} s"),
               Metric(f"{name}.profile_error_of_rho_g_H", profile, 0.01, "mean pressure of 10 depth layers"),
               Metric(f"{name}.density_deviation", dev, 0.01, "max |rho/rho0 - 1| below the surface layer"),
               Metric(f"{name}.kinetic_energy_left", decay, 0.1,
                      f"mean over the last {SETTLE_WINDOW:g} s / peak {peak:.2g} J{'/m' if dim == 2 else ''} "
                      f"at t = {float(times[np.argmax(ke)]):.2f} s")]
    if not opts.plot:
        return metrics
    plt = _plot()
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10, 4))
    ax.plot(p / (rho0 * g * H), y / H, ".", ms=2, label="particles")
    ax.plot((H - np.linspace(0, H, 10)) / H, np.linspace(0, H, 10) / H, "k-", label="rho0 g (H - y)")
    ax.set_xlabel("p / (rho0 g H)")
    ax.set_ylabel("y / H")
    ax.legend()
    bx.semilogy(times, np.maximum(ke, 1e-30))
    bx.set_xlabel("t (s)")
    bx.set_ylabel("kinetic energy (J/m)" if dim == 2 else "kinetic energy (J)")
    fig.suptitle(f"Hydrostatic tank, {dim}D, {sim.n_particles:,} particles")
    fig.tight_layout()
    fig.savefig(out / f"{name}.png", dpi=100)
    plt.close(fig)
    return metrics


def drop_semi_axes(omega: float, rate: float, radius: float, t_end: float, dt: float = 1.0e-4):
    """Exact semi-axes of the drop (Monaghan & Rafiee 2013): an incompressible 2D drop in the central
    field -omega^2 r with the velocity u = A x, v = -A y stays an ellipse a(t) b(t) = R^2 with
    a' = A a, b' = -A b and, from zero pressure on its boundary,
        A' = (A^2 + omega^2) (b^2 - a^2) / (a^2 + b^2).
    Integrated with classical Runge-Kutta; returns (t, a, b)."""
    def f(s):
        a, b, A = s
        return np.array([A * a, -A * b, (A * A + omega * omega) * (b * b - a * a) / (a * a + b * b)])
    n = int(math.ceil(t_end / dt))
    out = np.empty((n + 1, 3))
    s = np.array([radius, radius, rate], dtype=float)
    out[0] = s
    for k in range(n):
        k1 = f(s)
        k2 = f(s + 0.5 * dt * k1)
        k3 = f(s + 0.5 * dt * k2)
        k4 = f(s + dt * k3)
        s = s + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        out[k + 1] = s
    return np.arange(n + 1) * dt, out[:, 0], out[:, 1]


def _maxima(t, y):
    """Times and values of the local maxima of a sampled signal (parabola through each peak sample)."""
    found = []
    for k in range(1, len(y) - 1):
        if y[k] > y[k - 1] and y[k] >= y[k + 1]:
            denom = y[k - 1] - 2 * y[k] + y[k + 1]
            shift = 0.5 * (y[k - 1] - y[k + 1]) / denom if denom != 0 else 0.0
            h = 0.5 * (t[k + 1] - t[k - 1])
            found.append((t[k] + shift * h, y[k] - 0.25 * (y[k - 1] - y[k + 1]) * shift))
    return found


def oscillating_drop(quick: bool, out: Path, backend: str = "cpu", opts: CaseOptions | None = None) -> list[Metric]:
    """Drop in a central force field (Monaghan & Rafiee 2013): oscillation period and amplitude of the
    semi-axis against the exact ellipse solution (period 4.567375 s for omega = 1, A = 0.5)."""
    opts = opts or CaseOptions(backend)
    dx = opts.dx or (0.05 if quick else 0.025)
    scene = load_scene(CONFIGS / "oscillating_drop_2d.toml", [f"particles.spacing={dx}", *opts.overrides])
    omega, rate = scene.forces.central_omega, scene.fluid.flow_rate
    radius = scene.fluid.blocks[0].radius
    c = np.array(scene.fluid.flow_center[:2])
    t_end = 10.0  # two periods
    t_ref, a_ref, b_ref = drop_semi_axes(omega, rate, radius, t_end)
    ref_peaks = _maxima(t_ref, a_ref)
    sim = Simulation(scene, opts.precision, opts.backend)
    clock = _Clock(sim, opts, "oscillating_drop", t_end)

    def moments():
        x = sim.state.x[: sim.state.n_owned, :2] - c
        return np.mean(x[:, 0] ** 2), np.mean(x[:, 1] ** 2)
    # a uniform ellipse has <x^2> = a^2 / 4: semi-axes from the second moments, normalised by the
    # initial (lattice) disc so the discretisation of the circle does not bias them
    mx0, my0 = moments()
    times, a_sim, b_sim = [0.0], [radius], [radius]
    for _ in _sampled(sim, clock, t_end, 10):
        mx, my = moments()
        times.append(sim.t)
        a_sim.append(radius * math.sqrt(mx / mx0))
        b_sim.append(radius * math.sqrt(my / my0))
    clock.done()
    peaks = _maxima(np.array(times), np.array(a_sim))
    period_ref = ref_peaks[1][0] - ref_peaks[0][0]
    amp_ref = ref_peaks[0][1] - radius
    if len(peaks) >= 2:
        period_err = abs((peaks[1][0] - peaks[0][0]) - period_ref) / period_ref
        amp_err = abs((peaks[0][1] - radius) - amp_ref) / amp_ref
    else:
        period_err = amp_err = float("nan")
    note = f"exact {period_ref:.4f} s, {sim.n_particles} particles"
    if len(peaks) >= 2:
        note = f"{peaks[1][0] - peaks[0][0]:.4f} s vs " + note
    metrics = [Metric("oscillating_drop.period_relative", period_err, 0.02, note),
               Metric("oscillating_drop.amplitude_relative", amp_err, 0.05,
                      f"first maximum of a - R vs exact {amp_ref:.4f} m")]
    if not opts.plot:
        return metrics
    plt = _plot()
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(times, a_sim, label="a (x semi-axis), sphfluid")
    ax.plot(times, b_sim, label="b (y semi-axis), sphfluid")
    ax.plot(t_ref, a_ref, "k--", lw=1, label="exact (Monaghan & Rafiee 2013)")
    ax.plot(t_ref, b_ref, "k--", lw=1)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("semi-axis (m)")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(f"Oscillating drop, omega = {omega:g}, A = {rate:g}, dx = {dx:g} m")
    fig.tight_layout()
    fig.savefig(out / "oscillating_drop.png", dpi=100)
    plt.close(fig)
    return metrics


def poiseuille_velocity(y, t, F: float, nu: float, L: float, terms: int = 200):
    """Start-up channel flow between plates at y = 0 and y = L at rest, body force F from t = 0
    (Morris, Fox & Zhu 1997, eq. 21):
        u = F/(2 nu) y (L - y) - sum_n 4 F L^2 / (nu pi^3 (2n+1)^3) sin(pi y (2n+1) / L) e^{-(2n+1)^2 pi^2 nu t / L^2}"""
    y = np.asarray(y, dtype=float)
    u = F / (2.0 * nu) * y * (L - y)
    for n in range(terms):
        k = 2 * n + 1
        u = u - 4.0 * F * L**2 / (nu * math.pi**3 * k**3) * np.sin(math.pi * y * k / L) \
            * math.exp(-k * k * math.pi**2 * nu * t / L**2)
    return u


def couette_velocity(y, t, U: float, nu: float, L: float, terms: int = 200):
    """Start-up Couette flow: fluid at rest between plates at y = 0 (fixed) and y = L, which slides
    at U along x from t = 0 (Morris, Fox & Zhu 1997, section 4.2; the sine series of U y / L):
        u = U y / L - sum_n 2 U (-1)^(n+1) / (n pi) sin(n pi y / L) e^{-n^2 pi^2 nu t / L^2}"""
    y = np.asarray(y, dtype=float)
    u = U * y / L
    for n in range(1, terms + 1):
        u = u - 2.0 * U * (-1.0) ** (n + 1) / (n * math.pi) * np.sin(n * math.pi * y / L) \
            * math.exp(-n * n * math.pi**2 * nu * t / L**2)
    return u


def poiseuille(quick: bool, out: Path, backend: str = "cpu", opts: CaseOptions | None = None) -> list[Metric]:
    """Start-up Poiseuille flow against the series solution (Morris et al. 1997): the largest
    velocity error over the channel at five times up to the steady state, in units of u_max."""
    opts = opts or CaseOptions(backend)
    dx = opts.dx or (5.0e-5 if quick else 2.5e-5)
    scene = load_scene(CONFIGS / "poiseuille_2d.toml", [f"particles.spacing={dx}", *opts.overrides])
    F, nu, L = scene.forces.external[0], scene.sph.nu, scene.domain.size[1]
    return _start_up_flow(scene, opts, out, "poiseuille", scene.domain.center[1] - 0.5 * L, L, F * L**2 / (8.0 * nu),
                          lambda y, t: poiseuille_velocity(y, t, F, nu, L), "u_max", "Start-up Poiseuille flow")


def couette(quick: bool, out: Path, backend: str = "cpu", opts: CaseOptions | None = None) -> list[Metric]:
    """Start-up Couette flow (a sliding plate: a moving wall) against the series solution: the
    largest velocity error over the channel at five times up to the steady state, in units of U."""
    opts = opts or CaseOptions(backend)
    dx = opts.dx or (5.0e-5 if quick else 2.5e-5)
    scene = load_scene(CONFIGS / "couette_2d.toml", [f"particles.spacing={dx}", *opts.overrides])
    bottom, top = scene.domain.planes
    U, nu, L = top.velocity[0], scene.sph.nu, top.point[1] - bottom.point[1]
    return _start_up_flow(scene, opts, out, "couette", bottom.point[1], L, U,
                          lambda y, t: couette_velocity(y, t, U, nu, L), "U", "Start-up Couette flow")


def still_surface(sim, x_body: float, clearance: float, dx: float) -> float:
    """The height of the still water more than ``clearance`` (m) to either side of a floating body at
    x = ``x_body``: its top particle layer + dx / 2 (2D)."""
    x = sim.state.x[: sim.state.n_owned]
    far = np.abs(x[:, 0] - x_body) > clearance
    return float(x[far, 1].max()) + 0.5 * dx


def floating_box(quick: bool, out: Path, backend: str = "cpu", opts: CaseOptions | None = None) -> list[Metric]:
    """A box of half the water's density floating in a tank (a floating body, heave only): its mean
    draft over the last two seconds of four against Archimedes' (density ratio x height)."""
    opts = opts or CaseOptions(backend)
    dx = opts.dx or (0.02 if quick else 0.01)
    scene = load_scene(CONFIGS / "floating_box_2d.toml", [f"particles.spacing={dx}", *opts.overrides])
    box = scene.obstacles[0]
    height = box.size[1]
    expected = box.density / scene.fluid.rest_density * height
    sim = Simulation(scene, opts.precision, opts.backend)
    body = sim.model.walls.bodies[0]
    t_end, window = 4.0, 2.0
    clock = _Clock(sim, opts, "floating_box", t_end)
    times, drafts, forces = [], [], []
    for _ in _sampled(sim, clock, t_end, 20):
        surface = still_surface(sim, box.center[0], box.size[0] / 2 + 0.2, dx)
        bottom = box.center[1] + body.x[1] - 0.5 * height
        times.append(sim.t)
        drafts.append(surface - bottom)
        forces.append(body.force[1] / (body.mass * abs(scene.forces.gravity[1])))
    clock.done()
    times, drafts, forces = np.array(times), np.array(drafts), np.array(forces)
    late = times >= t_end - window
    draft = float(drafts[late].mean())
    metrics = [Metric("floating_box.draft_relative", abs(draft - expected) / expected, 0.05,
                      f"mean draft {100 * draft:.2f} cm over t = {t_end - window:g}-{t_end:g} s vs {100 * expected:.2f} cm; "
                      f"{sim.n_particles} particles"),
               Metric("floating_box.buoyancy_relative", abs(float(forces[late].mean()) - 1.0), 0.05,
                      "mean fluid force / weight over the same window")]
    if not opts.plot:
        return metrics
    plt = _plot()
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(times, 100 * drafts, "-", lw=1, label="draft (sphfluid)")
    ax.axhline(100 * expected, color="k", lw=0.8, ls="--", label="Archimedes")
    ax.axvspan(t_end - window, t_end, color="0.9", label="averaged")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("draft (cm)")
    ax.legend(fontsize=8)
    ax.set_title(f"Floating box, density {box.density:g} kg/m^3, heave only, dx = {dx:g} m")
    fig.tight_layout()
    fig.savefig(out / "floating_box.png", dpi=100)
    plt.close(fig)
    return metrics


def body_angle(body) -> float:
    """A 2D floating body's turn about z since the scene placed it (degrees, in (-180, 180])."""
    return math.degrees(math.atan2(body.R[1, 0], body.R[0, 0]))


def floating_square(quick: bool, out: Path, backend: str = "cpu", opts: CaseOptions | None = None) -> list[Metric]:
    """A square log of half the water's density (a floating body free to turn): released flat, 5
    degrees off, it rolls over and floats corner down, a diagonal vertical. Flat is unstable for a
    square of relative density s = 1/2 (metacentric height KB + BM - KG = a/4 + a/6 - a/2 = -a/12),
    and for 1/4 < s < 3/4 the stable attitude is at 45 degrees (the classical result for square
    prisms: e.g. Reid 1963; Delbourgo 1987, "The floating plank", Am. J. Phys. 55:799). At 45 degrees
    with s = 1/2 the waterline runs through two corners, so the centre floats on the surface. Metrics:
    the mean angle and the centre's height above the still water by the walls over t = 3-5 s."""
    opts = opts or CaseOptions(backend)
    dx = opts.dx or (0.02 if quick else 0.01)
    scene = load_scene(CONFIGS / "floating_square_2d.toml", [f"particles.spacing={dx}", *opts.overrides])
    log_ = scene.obstacles[0]
    side = log_.size[0]
    sim = Simulation(scene, opts.precision, opts.backend)
    body = sim.model.walls.bodies[0]
    t_end, window = 5.0, 2.0
    clock = _Clock(sim, opts, "floating_square", t_end)
    times, angles, heights = [], [], []
    for _ in _sampled(sim, clock, t_end, 20):
        centre = np.array(log_.center[:2]) + body.x[:2]
        surface = still_surface(sim, centre[0], 0.5 * math.sqrt(2.0) * side + 0.1, dx)
        times.append(sim.t)
        angles.append(log_.rotation[2] + body_angle(body))
        heights.append(centre[1] - surface)
    clock.done()
    times, angles, heights = np.array(times), np.array(angles), np.array(heights)
    late = times >= t_end - window
    angle, height = float(angles[late].mean()), float(heights[late].mean())
    metrics = [Metric("floating_square.angle_error_deg", abs(abs(angle) - 45.0), 2.0,
                      f"mean angle {angle:.2f} degrees over t = {t_end - window:g}-{t_end:g} s vs 45 (corner down); "
                      f"range {angles[late].min():.2f}-{angles[late].max():.2f}; {sim.n_particles} particles"),
               Metric("floating_square.centre_height_of_side", abs(height) / side, 0.05,
                      f"mean height of the centre above the surface {100 * height:+.2f} cm over the same window vs 0 "
                      f"(side {100 * side:g} cm)")]
    if not opts.plot:
        return metrics
    plt = _plot()
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(10, 3.8), gridspec_kw={"width_ratios": [1.3, 1]})
    ax.plot(times, angles, "-", lw=1, label="angle (sphfluid)")
    ax.axhline(45.0, color="k", lw=0.8, ls="--", label="stable: 45 degrees")
    ax.axhline(0.0, color="0.5", lw=0.8, ls=":", label="flat: unstable")
    ax.axvspan(t_end - window, t_end, color="0.9", label="averaged")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("angle (degrees)")
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title(f"Square log, density {log_.density:g} kg/m^3, dx = {dx:g} m")
    s = sim.state
    x = s.x[: s.n_owned]
    ax2.scatter(x[:, 0], x[:, 1], s=1.5 if quick else 0.5, c="tab:blue", lw=0)
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1], [-1, -1]]) * 0.5 * side
    turn = math.radians(angles[-1])
    rot = np.array([[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]])
    outline = corners @ rot.T + np.array(log_.center[:2]) + body.x[:2]
    ax2.fill(outline[:, 0], outline[:, 1], color="#b0a088", ec="k", lw=0.8)
    ax2.set_aspect("equal")
    ax2.set_xlim(scene.domain.center[0] - 0.5 * scene.domain.size[0], scene.domain.center[0] + 0.5 * scene.domain.size[0])
    ax2.set_ylim(0.0, scene.domain.center[1] + 0.5 * scene.domain.size[1])
    ax2.set_title(f"t = {sim.t:.1f} s", fontsize=10)
    fig.tight_layout()
    fig.savefig(out / "floating_square.png", dpi=100)
    plt.close(fig)
    return metrics


def faxen_drag(k: float) -> float:
    """F / (mu U) per unit length of a cylinder of radius a moving along and midway between two plane
    walls 2 l apart in Stokes flow, k = a / l < 1/2 (Faxen 1946, as quoted by Happel & Brenner 1965
    and Ben Richou, Ambari & Naciri 2004). Checked independently here: Taylor-Hood finite elements
    give 21.957 at k = 1/4 against the series' 21.964 (scripts/investigations/faxen_fem_check.py)."""
    series = -math.log(k) - 0.9157 + 1.7244 * k ** 2 - 1.7302 * k ** 4 + 2.4056 * k ** 6 - 4.5913 * k ** 8
    return 4.0 * math.pi / series


def settling_cylinder(quick: bool, out: Path, backend: str = "cpu", opts: CaseOptions | None = None) -> list[Metric]:
    """A cylinder of twice the water's density settling midway between two walls at Re ~ 0.04 (a
    floating body moved by the fluid's viscous and pressure forces) under a free surface: its mean
    velocity over the last 0.15 s of 0.4 s against the terminal velocity at which Faxen's Stokes drag
    balances its weight less its buoyancy, U = (rho_s - rho) g pi a^2 / (mu lambda(a / l))."""
    return _settling("settling_cylinder", "settling_cylinder_2d.toml", quick, out, opts or CaseOptions(backend))


def settling_cylinder_closed(quick: bool, out: Path, backend: str = "cpu",
                             opts: CaseOptions | None = None) -> list[Metric]:
    """The same cylinder in a closed box full of water with the hydrostatic pressure removed
    (forces.hydrostatic = "removed": the fluid under its modified pressure, the body under its
    weight less its buoyancy), against the same terminal velocity."""
    return _settling("settling_cylinder_closed", "settling_cylinder_closed_2d.toml", quick, out,
                     opts or CaseOptions(backend))


def faxen_terminal_speed(scene) -> float:
    """m/s: the settling cylinder's (obstacles[0]) terminal speed between the walls of a channel
    domain.size[0] wide, (rho_b - rho0) g pi a^2 = mu U lambda(a / half-width) (faxen_drag)."""
    body, half = scene.obstacles[0], 0.5 * scene.domain.size[0]
    rho, mu = scene.fluid.rest_density, scene.fluid.rest_density * scene.sph.nu
    g = abs(scene.forces.gravity[1])
    return (body.density - rho) * g * math.pi * body.radius ** 2 / (mu * faxen_drag(body.radius / half))


def _settling(name: str, config: str, quick: bool, out: Path, opts: CaseOptions) -> list[Metric]:
    """The settling cylinder cases: scene ``config``, metric and plot named ``name``."""
    dx = opts.dx or (5.0e-4 if quick else 2.5e-4)
    scene = load_scene(CONFIGS / config, [f"particles.spacing={dx}", *opts.overrides])
    body_spec = scene.obstacles[0]
    a, half = body_spec.radius, 0.5 * scene.domain.size[0]
    terminal = faxen_terminal_speed(scene)
    sim = Simulation(scene, opts.precision, opts.backend)
    body = sim.model.walls.bodies[0]
    t_end, window = 0.4, 0.15
    clock = _Clock(sim, opts, name, t_end)
    times, speeds = [], []
    for _ in _sampled(sim, clock, t_end, 10):
        times.append(sim.t)
        speeds.append(-body.v[1])
    clock.done()
    times, speeds = np.array(times), np.array(speeds)
    late = times >= t_end - window
    speed = float(speeds[late].mean())
    metrics = [Metric(f"{name}.terminal_velocity_relative", abs(speed / terminal - 1.0), 0.05,
                      f"mean settling speed {1e3 * speed:.3f} mm/s over t = {t_end - window:g}-{t_end:g} s vs "
                      f"{1e3 * terminal:.3f} mm/s (Faxen, a / l = {a / half:g}, Re = {terminal * 2 * a / scene.sph.nu:.3f}); "
                      f"{sim.n_particles} particles, {a / dx:g} spacings per radius")]
    # a terminal velocity is steady: the fluid's slowest transient (diffusion across the channel,
    # (2 l)^2 / (pi^2 nu) = 0.04 s) has died out long before the window, so the speed may not change there by
    # more than the case's own tolerance (a mean that crosses Faxen's speed on its way elsewhere fails)
    slope = np.polyfit(times[late], speeds[late], 1)[0]
    metrics.append(Metric(f"{name}.speed_drift_relative", abs(slope * window / speed), 0.05,
                          f"the settling speed's change over t = {t_end - window:g}-{t_end:g} s (a fitted line) "
                          f"{1e3 * slope * window:+.3f} mm/s, of its mean {1e3 * speed:.3f} mm/s"))
    if not opts.plot:
        return metrics
    plt = _plot()
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.plot(times, speeds / terminal, "-", lw=1, label="settling speed (sphfluid)")
    ax.axhline(1.0, color="k", lw=0.8, ls="--", label="Faxen's terminal velocity")
    ax.axvspan(t_end - window, t_end, color="0.9", label="averaged")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("speed / terminal speed")
    ax.legend(fontsize=8)
    how = "closed box, hydrostatics removed" if scene.forces.hydrostatic == "removed" else "free surface"
    ax.set_title(f"Settling cylinder ({how}), a / l = {a / half:g}, dx = {dx:g} m", fontsize=10)
    fig.tight_layout()
    fig.savefig(out / f"{name}.png", dpi=100)
    plt.close(fig)
    return metrics


def mls_velocity(x, v, points, H: float):
    """Velocity at each of ``points`` (k, 2) from the particles at ``x`` (n, 2) with velocities ``v``
    (n, 2): the value at the point of the linear field u(y) = a + B (y - point) fitted by least
    squares to the particles within the support H, weighted by the Wendland C2 kernel (moving least
    squares, first order; Dilts 1999, Int. J. Numer. Meth. Eng. 44:1115). A Shepard average is
    exact only for a constant field and near a wall reads the value at the centroid of the fluid in
    the support, a fraction of H inside (docs/USAGE.md, Probes); the linear fit is exact for a linear
    field there too, so a profile against a wall is not biased by the measurement."""
    values = np.empty((len(points), v.shape[1]))
    for k, point in enumerate(points):
        offset = x - point
        q = np.sqrt(np.einsum("ij,ij->i", offset, offset)) / H
        near = q < 1.0
        weight = (1.0 - q[near]) ** 4 * (1.0 + 4.0 * q[near])
        basis = np.column_stack([np.ones(near.sum()), offset[near]])
        moments = basis.T @ (weight[:, None] * basis)
        values[k] = np.linalg.solve(moments, basis.T @ (weight[:, None] * v[near]))[0]
    return values


def largest_gap(x, lo, hi, spacing: float, margin: float = 0.0):
    """The largest distance from a point of the box [lo + margin, hi - margin] (sampled every half
    spacing) to its nearest particle, and that point: a particle lattice gives 0.71 spacings (0.5 at
    a wall), a disordered one about 1; a void opened by tensile instability (negative pressure
    pulling particles apart) is a hole several spacings wide."""
    axes = [np.arange(a + margin, b - margin + 0.25 * spacing, 0.5 * spacing) for a, b in zip(lo, hi)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(axes))
    gap, where = 0.0, grid[0]
    for chunk in np.array_split(grid, max(1, len(grid) // 256)):
        d2 = np.min(np.sum((chunk[:, None, :] - x[None, :, :]) ** 2, axis=2), axis=1)
        if np.sqrt(d2.max()) > gap:
            gap, where = float(np.sqrt(d2.max())), chunk[np.argmax(d2)]
    return gap, where


# The cavity is at steady state from about 7 lid transits on (L / U = 1 s; 40 across: the RMS of
# single snapshots falls to its level by t = 7 s and stays there to t = 30 s); WCSPH's particle
# noise makes one snapshot's profile scatter by about 1 % of U, so the metric averages the profiles
# sampled every CAVITY_SAMPLE_DT over the last part of the run.
CAVITY_SAMPLE_DT = 0.5  # s


def cavity(quick: bool, out: Path, backend: str = "cpu", opts: CaseOptions | None = None) -> list[Metric]:
    """The lid-driven cavity at Re = 100 (a moving wall in a closed box) against Ghia, Ghia & Shin
    (1982) Tables I and II: u along x = 0.5 and v along y = 0.5 at their interior points, from the
    profiles averaged over the steady part of the run, in units of the lid speed U."""
    opts = opts or CaseOptions(backend)
    dx = opts.dx or (0.025 if quick else 0.0125)
    scene = load_scene(CONFIGS / "cavity_2d.toml", [f"particles.spacing={dx}", *opts.overrides])
    lid = scene.domain.planes[-1]
    U, L = lid.velocity[0], lid.point[1]
    H = scene.sph.support * dx
    t_end, t_from = (10.0, 5.0) if quick else (20.0, 10.0)
    inner_y, inner_x = (GHIA_Y > 0) & (GHIA_Y < 1), (GHIA_X > 0) & (GHIA_X < 1)
    line = np.linspace(0.0, 1.0, 101)
    points_u = L * np.column_stack([np.full(inner_y.sum() + line.size, 0.5), np.r_[GHIA_Y[inner_y], line]])
    points_v = L * np.column_stack([np.r_[GHIA_X[inner_x], line], np.full(inner_x.sum() + line.size, 0.5)])
    sim = Simulation(scene, opts.precision, opts.backend)
    clock = _Clock(sim, opts, "cavity", t_end)
    samples_u, samples_v = [], []
    for t_out in np.arange(t_from + CAVITY_SAMPLE_DT, t_end + 1e-9, CAVITY_SAMPLE_DT):
        while sim.t < t_out:
            sim.step(dt_cap=t_out - sim.t)
            clock.tick()
        n = sim.state.n_owned
        x, v = sim.state.x[:n, :2].astype(np.float64), sim.synchronised_velocity()[:n, :2].astype(np.float64)
        samples_u.append(mls_velocity(x, v, points_u, H)[:, 0] / U)
        samples_v.append(mls_velocity(x, v, points_v, H)[:, 1] / U)
    clock.done()
    samples_u, samples_v = np.array(samples_u), np.array(samples_v)
    m_u, m_v = inner_y.sum(), inner_x.sum()
    error = np.r_[samples_u[:, :m_u].mean(axis=0) - GHIA_U_RE100[inner_y],
                  samples_v[:, :m_v].mean(axis=0) - GHIA_V_RE100[inner_x]]
    half = len(samples_u) // 2
    drift = max(float(np.max(np.abs(s[half:, :m].mean(axis=0) - s[:half, :m].mean(axis=0))))
                for s, m in ((samples_u, m_u), (samples_v, m_v)))
    gap, where = largest_gap(x, (0.0, 0.0), (L, L), dx)
    bulk, _ = largest_gap(x, (0.0, 0.0), (L, L), dx, margin=H)
    log.info("cavity: mean profile - Ghia (u / U at y = %s; v / U at x = %s): %s",
             ", ".join(f"{y:g}" for y in GHIA_Y[inner_y]), ", ".join(f"{a:g}" for a in GHIA_X[inner_x]),
             " ".join(f"{e:+.4f}" for e in error))
    window = f"t = {t_from:g}-{t_end:g} s"
    metrics = [Metric("cavity.centreline_rms_of_U", float(np.sqrt(np.mean(error**2))), 0.03,
                      f"{error.size} points of Ghia's Tables I-II, {len(samples_u)} profiles over {window}; "
                      f"{sim.n_particles} particles"),
               Metric("cavity.centreline_max_of_U", float(np.max(np.abs(error))), 0.10,
                      f"at {'u, y' if np.argmax(np.abs(error)) < m_u else 'v, x'} = "
                      f"{np.r_[GHIA_Y[inner_y], GHIA_X[inner_x]][np.argmax(np.abs(error))]:g}; "
                      f"the window's halves differ by up to {drift:.4f}"),
               Metric("cavity.largest_gap_of_dx", gap / dx, 1.5,
                      f"distance to the nearest particle at t = {sim.t:g} s, at ({where[0] / L:.3g}, "
                      f"{where[1] / L:.3g}) L; farther than H from the walls: {bulk / dx:.3g}")]
    if not opts.plot:
        return metrics
    plt = _plot()
    fig, (ax_u, ax_v, ax_p) = plt.subplots(1, 3, figsize=(13, 4.2))
    ax_u.plot(samples_u[:, m_u:].mean(axis=0), line, "-", lw=1.2, label=f"sphfluid, mean over {window}")
    ax_u.plot(samples_u[-1, m_u:], line, ":", lw=0.8, color="C0", label=f"sphfluid at t = {sim.t:g} s")
    ax_u.plot(GHIA_U_RE100, GHIA_Y, "ks", mfc="none", ms=5, label="Ghia et al. 1982, Table I")
    ax_u.set_xlabel("u / U on x = 0.5")
    ax_u.set_ylabel("y / L")
    ax_u.legend(fontsize=7)
    ax_v.plot(line, samples_v[:, m_v:].mean(axis=0), "-", lw=1.2, label=f"sphfluid, mean over {window}")
    ax_v.plot(line, samples_v[-1, m_v:], ":", lw=0.8, color="C0", label=f"sphfluid at t = {sim.t:g} s")
    ax_v.plot(GHIA_X, GHIA_V_RE100, "ks", mfc="none", ms=5, label="Ghia et al. 1982, Table II")
    ax_v.set_xlabel("x / L")
    ax_v.set_ylabel("v / U on y = 0.5")
    ax_v.legend(fontsize=7)
    speed = np.hypot(v[:, 0], v[:, 1]) / U
    dots = ax_p.scatter(x[:, 0] / L, x[:, 1] / L, c=speed, s=max(0.5, 4000.0 / len(x)), cmap="viridis", vmin=0, vmax=1)
    fig.colorbar(dots, ax=ax_p, label="|v| / U")
    ax_p.set_aspect("equal")
    ax_p.set_xlim(0, 1)
    ax_p.set_ylim(0, 1)
    ax_p.set_title(f"particles at t = {sim.t:g} s", fontsize=9)
    fig.suptitle(f"Lid-driven cavity, Re = {U * L / scene.sph.nu:g}, {round(L / dx)} across, "
                 f"c0 = {scene.sph.sound_speed / U:g} U")
    fig.tight_layout()
    fig.savefig(out / "cavity.png", dpi=100)
    plt.close(fig)
    return metrics


def _start_up_flow(scene, opts, out, name, y0, L, scale, exact, scale_name, title) -> list[Metric]:
    """A channel flow from rest between plates at y0 and y0 + L against its series solution
    ``exact(y, t)``: the largest velocity error at Morris et al.'s five times, over ``scale``."""
    sim = Simulation(scene, opts.precision, opts.backend)
    times = (0.0225, 0.045, 0.1125, 0.225, 1.0)  # Morris et al.'s figures 2 and 4
    clock = _Clock(sim, opts, name, times[-1])
    profiles, worst = [], 0.0
    for t_out in times:
        while sim.t < t_out:
            sim.step(dt_cap=t_out - sim.t)
            clock.tick()
        n = sim.state.n_owned
        y = sim.state.x[:n, 1] - y0
        u = sim.synchronised_velocity()[:n, 0]
        worst = max(worst, float(np.max(np.abs(u - exact(y, sim.t)))) / scale)
        profiles.append((sim.t, y.copy(), u.copy()))
    clock.done()
    metrics = [Metric(f"{name}.velocity_error_of_{scale_name}", worst, 0.02,
                      f"max over {sim.n_particles} particles at t = {', '.join(f'{t:g}' for t in times)} s")]
    if not opts.plot:
        return metrics
    plt = _plot()
    fig, ax = plt.subplots(figsize=(6, 4))
    yy = np.linspace(0.0, L, 200)
    for k, (t, y, u) in enumerate(profiles):
        ax.plot(y / L, u / scale, ".", ms=3, color=f"C{k}", label=f"t = {t:g} s")
        ax.plot(yy / L, exact(yy, t) / scale, "-", lw=1, color=f"C{k}")
    ax.set_xlabel("y / L")
    ax.set_ylabel(f"u / {scale_name}")
    ax.legend(fontsize=8)
    ax.set_title(f"{title} (dots: sphfluid, lines: series), {round(L / scene.particles.spacing)} across")
    fig.tight_layout()
    fig.savefig(out / f"{name}.png", dpi=100)
    plt.close(fig)
    return metrics


def hydrostatic_3d(quick: bool, out: Path, backend: str = "cpu", opts: CaseOptions | None = None) -> list[Metric]:
    """The hydrostatic tank in 3D."""
    return hydrostatic(quick, out, backend, opts, dim=3)


def dam_break_3d(quick: bool, out: Path, backend: str = "cpu", opts: CaseOptions | None = None) -> list[Metric]:
    """The dam break in 3D (the 2D column extruded, periodic across) against Martin & Moyce."""
    return dam_break(quick, out, backend, opts, dim=3)


# The probes of the hydrostatic tank: pressure at five depths on the centre line and on the side
# wall, the free-surface height at three places (sphcore/probes.py)
PROBE_DEPTHS = (0.05, 0.15, 0.25, 0.35, 0.45)  # y (m) of the pressure probes; the fill height is 0.5 m
PROBE_HEIGHT_X = (0.1, 0.25, 0.4)              # x (m) of the height probes


def hydrostatic_probes(quick: bool, out: Path, backend: str = "cpu", opts: CaseOptions | None = None) -> list[Metric]:
    """The 2D hydrostatic tank measured by its probes ([[probes]], every 10 steps): the pressure
    probes against rho0 g (H0 - y) and the height probes against the fill height H0 (the block's
    top, 0.5 m), each averaged over the samples of the last SETTLE_WINDOW seconds."""
    from sphcore.scene import scene_from_dict
    opts = opts or CaseOptions(backend)
    dx = opts.dx or (0.02 if quick else 0.01)
    base = load_scene(CONFIGS / "hydrostatic_2d.toml", [f"particles.spacing={dx}", *opts.overrides])
    fill = base.fluid.blocks[0].max[1]
    width = base.fluid.blocks[0].max[0]
    probes = ([{"name": f"p_centre_{y:g}", "kind": "pressure", "at": [0.5 * width, y]} for y in PROBE_DEPTHS]
              + [{"name": f"p_wall_{y:g}", "kind": "pressure", "at": [0.0, y]} for y in PROBE_DEPTHS]
              + [{"name": f"h_{x:g}", "kind": "height", "at": [x, 0.1]} for x in PROBE_HEIGHT_X])
    data = base.to_dict()
    data["probes"] = probes
    data["output"]["probes_every"] = 10
    scene = scene_from_dict(data, source=base.source)
    rho0, g = scene.fluid.rest_density, abs(scene.forces.gravity[1])
    sim = Simulation(scene, opts.precision, opts.backend)
    t_end = 3.0
    clock = _Clock(sim, opts, "hydrostatic_probes", t_end)
    kept = []
    while sim.t < t_end:
        sim.step(dt_cap=t_end - sim.t)
        clock.tick()
        kept += [values for step, t, values in sim.probes.take_samples() if t >= t_end - SETTLE_WINDOW]
    clock.done()
    mean = np.mean(kept, axis=0)
    names = sim.probes.names
    at = {n: p.at for n, p in zip(names, scene.probes)}
    scale = rho0 * g * fill
    errors = {n: (v - rho0 * g * (fill - at[n][1])) / scale for n, v in zip(names, mean) if n.startswith("p_")}
    heights = {n: (v - fill) / dx for n, v in zip(names, mean) if n.startswith("h_")}
    centre = max(abs(errors[n]) for n in errors if n.startswith("p_centre"))
    wall = max(abs(errors[n]) for n in errors if n.startswith("p_wall"))
    height = max(abs(h) for h in heights.values())
    shown = ", ".join(f"{n} {100 * e:+.2f} %" for n, e in errors.items())
    log.info("hydrostatic_probes: pressure error of rho0 g H0 (mean of %d samples): %s", len(kept), shown)
    log.info("hydrostatic_probes: height - H0 in spacings: %s", ", ".join(f"{n} {h:+.3f}" for n, h in heights.items()))
    metrics = [Metric("hydrostatic_probes.centre_p_of_rho_g_H", centre, 0.01,
                      f"max |p - rho0 g (H0 - y)| of {len(PROBE_DEPTHS)} probes at x = {0.5 * width:g} m"),
               Metric("hydrostatic_probes.wall_p_of_rho_g_H", wall, 0.01,
                      "the same on the side wall x = 0"),
               Metric("hydrostatic_probes.height_of_dx", height, 0.25,
                      f"max |h - H0| / dx of {len(PROBE_HEIGHT_X)} height probes, H0 = {fill:g} m")]
    if not opts.plot:
        return metrics
    plt = _plot()
    fig, ax = plt.subplots(figsize=(5, 4))
    y = np.linspace(0.0, fill, 10)
    ax.plot(rho0 * g * (fill - y) / scale, y, "k-", label="rho0 g (H0 - y)")
    for prefix, marker in (("p_centre", "o"), ("p_wall", "s")):
        ys = [at[n][1] for n in names if n.startswith(prefix)]
        ps = [v / scale for n, v in zip(names, mean) if n.startswith(prefix)]
        ax.plot(ps, ys, marker, mfc="none", label=f"probes {prefix[2:]}")
    for n, v in zip(names, mean):
        if n.startswith("h_"):
            ax.axhline(v, color="tab:blue", lw=0.5)
    ax.set_xlabel("p / (rho0 g H0)")
    ax.set_ylabel("y (m); thin lines: the height probes")
    ax.legend()
    fig.suptitle(f"Hydrostatic tank probes, 2D, {sim.n_particles:,} particles")
    fig.tight_layout()
    fig.savefig(out / "hydrostatic_probes.png", dpi=100)
    plt.close(fig)
    return metrics


# Buchner (2002) wall pressure in the 2D dam break (configs/dam_break_pressure_2d.toml): the digitised
# experiment, copied from TrixiParticles.jl (the file's header names the source)
BUCHNER_DATA = Path(__file__).resolve().parent / "data" / "buchner_2002_pressure.csv"
# Each sensor's first-impact window in t* = t sqrt(g / H), fixed from the experiment's record alone:
# P1 from before the surge arrives (t* 2.47) over the impact peak (2.77) and the relaxation to the
# plateau, ending before the second rise (5.3, the plunging jet's return); P2 over its one hump
# (rise from 4.6, peak 5.6, back to ~0 by 6.3) from the first recorded sample
PRESSURE_WINDOWS = {"P1": (2.0, 4.0), "P2": (3.1, 7.0)}
PRESSURE_TOLERANCE = 0.15  # the issue's target for peak and impulse, each sensor
# The labelled filter: a centred moving average of the probe signal over 10 ms (t* 0.040), the first
# zero of its response at 100 Hz; it removes the weakly compressible fluid's acoustic noise
# (c0 / H_support ~ 1 kHz at H / 40) and keeps the impact's rise (~50 ms in the experiment at P1)
PRESSURE_FILTER_S = 0.010
# The run's end: the last window's end (the experiment's records go on to t* 7.30 and 7.52). Run to
# t* 7.5, the full resolution (H / 80) stopped at t* 7.497 on run.max_density_ratio (rho/rho0 4.12,
# docs/VALIDATION.md): after both windows, so it changes no metric, but the run must finish to report
PRESSURE_END_T_STAR = 7.0


def load_buchner(path: Path = BUCHNER_DATA) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The experiment's records: {sensor: (t*, p*)}, t* = t sqrt(g / H), p* = p / (rho g H), each in
    increasing t*."""
    lines = [line for line in Path(path).read_text().splitlines() if line.strip() and not line.startswith("#")]
    if lines[0] != "sensor,t_star,p_star":
        raise ValueError(f"{path}: header {lines[0]!r}, expected 'sensor,t_star,p_star'")
    columns = {}
    for line in lines[1:]:
        sensor, t, p = line.split(",")
        columns.setdefault(sensor, []).append((float(t), float(p)))
    data = {}
    for sensor, rows in sorted(columns.items()):
        t, p = np.array(rows).T
        order = np.argsort(t, kind="stable")
        data[sensor] = (t[order], p[order])
    return data


def moving_average(t, p, window: float) -> np.ndarray:
    """Centred moving average of a signal sampled at increasing (possibly uneven) times t over
    ``window`` (same unit as t): the mean of the piecewise linear signal over [t - w/2, t + w/2],
    the interval cut to the record at its ends."""
    t, p = np.asarray(t, dtype=float), np.asarray(p, dtype=float)
    integral = np.concatenate([[0.0], np.cumsum(0.5 * (p[1:] + p[:-1]) * np.diff(t))])
    lo, hi = np.maximum(t - 0.5 * window, t[0]), np.minimum(t + 0.5 * window, t[-1])
    span = hi - lo
    mean = (np.interp(hi, t, integral) - np.interp(lo, t, integral)) / np.where(span > 0.0, span, 1.0)
    return np.where(span > 0.0, mean, p)


def peak_and_impulse(t, p, lo: float, hi: float) -> tuple[float, float, float]:
    """(largest p, time of it, integral of the piecewise linear p over [lo, hi]) of a signal at
    increasing times t."""
    t, p = np.asarray(t, dtype=float), np.asarray(p, dtype=float)
    inside = (t > lo) & (t < hi)
    tt = np.concatenate([[lo], t[inside], [hi]])
    pp = np.concatenate([[np.interp(lo, t, p)], p[inside], [np.interp(hi, t, p)]])
    k = int(np.argmax(pp))
    return float(pp[k]), float(tt[k]), float(np.sum(0.5 * (pp[1:] + pp[:-1]) * np.diff(tt)))


def dam_break_pressure(quick: bool, out: Path, backend: str = "cpu", opts: CaseOptions | None = None) -> list[Metric]:
    """The 2D dam break of Buchner's experiment (2H x H column, H = 0.6 m): the wall pressure probes
    P1 and P2 against the measured records, peak and impulse over each sensor's first-impact window
    (PRESSURE_WINDOWS), of the raw probe signal (sampled every step) and, separately, of its
    PRESSURE_FILTER_S moving average."""
    opts = opts or CaseOptions(backend)
    dx = opts.dx or (0.015 if quick else 0.0075)
    scene = load_scene(CONFIGS / "dam_break_pressure_2d.toml", [f"particles.spacing={dx}", *opts.overrides])
    dx = scene.particles.spacing
    H = scene.fluid.blocks[0].max[1] - scene.fluid.blocks[0].min[1]
    rho0, g = scene.fluid.rest_density, abs(scene.forces.gravity[1])
    t_scale, p_scale = math.sqrt(g / H), rho0 * g * H
    data = load_buchner()
    sim = Simulation(scene, opts.precision, opts.backend)
    names = sim.probes.names
    t_end = PRESSURE_END_T_STAR / t_scale
    clock = _Clock(sim, opts, "dam_break_pressure", t_end)
    times, values = [0.0], [np.zeros(len(names))]
    while sim.t < t_end:
        sim.step(dt_cap=t_end - sim.t)
        clock.tick()
        for step, t, v in sim.probes.take_samples():
            times.append(t)
            values.append(np.asarray(v, dtype=float))
    clock.done()
    t_star = np.asarray(times) * t_scale
    raw = {n: np.array([v[k] for v in values]) / p_scale for k, n in enumerate(names)}
    filtered = {n: moving_average(t_star, raw[n], PRESSURE_FILTER_S * t_scale) for n in names}
    metrics, shown = [], []
    for sensor in ("P1", "P2"):
        lo, hi = PRESSURE_WINDOWS[sensor]
        t_exp, p_exp = data[sensor]
        peak_exp, when_exp, impulse_exp = peak_and_impulse(t_exp, p_exp, lo, hi)
        for label, signal in (("raw", raw[sensor]), ("filtered", filtered[sensor])):
            peak, when, impulse = peak_and_impulse(t_star, signal, lo, hi)
            shown.append(f"{sensor} {label}: peak {peak:.3f} at t* {when:.3f}, impulse {impulse:.3f}")
            where = f"t* {lo:g}-{hi:g}" + ("" if label == "raw" else f", {1e3 * PRESSURE_FILTER_S:g} ms moving average")
            metrics.append(Metric(f"dam_break_pressure.{sensor}_peak_{label}_relative", abs(peak / peak_exp - 1.0),
                                  PRESSURE_TOLERANCE,
                                  f"p*/(rho g H) {peak:.3f} at t* {when:.2f} vs Buchner {peak_exp:.3f} at "
                                  f"{when_exp:.2f}; {where}"))
            metrics.append(Metric(f"dam_break_pressure.{sensor}_impulse_{label}_relative",
                                  abs(impulse / impulse_exp - 1.0), PRESSURE_TOLERANCE,
                                  f"integral of p* dt* {impulse:.4f} vs Buchner {impulse_exp:.4f}; {where}"
                                  + (f"; {sim.n_particles} particles, H / {H / dx:.0f}" if label == "raw" else "")))
    log.info("dam_break_pressure: %s", "; ".join(shown))
    opts.stats.update(pressure_t_star=t_star.tolist(), pressure_raw={n: raw[n].tolist() for n in names})
    if not opts.plot:
        return metrics
    plt = _plot()
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    for ax, sensor in zip(axes, ("P1", "P2")):
        lo, hi = PRESSURE_WINDOWS[sensor]
        ax.axvspan(lo, hi, color="0.93", label="first-impact window (metrics)")
        ax.plot(t_star, raw[sensor], "-", lw=0.5, color="C0", alpha=0.6, label="sphfluid, raw probe (every step)")
        ax.plot(t_star, filtered[sensor], "-", lw=1.4, color="C3",
                label=f"sphfluid, {1e3 * PRESSURE_FILTER_S:g} ms moving average")
        ax.plot(*data[sensor], "k^", ms=4, mfc="none", label="Buchner 2002 (experiment)")
        ax.set_xlim(2.0, PRESSURE_END_T_STAR)
        top = max(1.2 * float(np.max(data[sensor][1])), 1.1 * float(np.max(filtered[sensor][t_star >= 2.0])))
        ax.set_ylim(-0.1 * top, top)
        ax.set_xlabel("t* = t sqrt(g / H)")
        ax.set_ylabel("p / (rho g H)")
        ax.set_title(f"{sensor}, y = {scene.probes[names.index(sensor)].at[1]:g} m on the downstream wall")
        ax.legend(fontsize=7, loc="upper left")
    fig.suptitle(f"2D dam break wall pressure, H / {H / dx:.0f} ({sim.n_particles:,} particles), "
                 f"c0 = {scene.sph.sound_speed:g} m/s")
    fig.tight_layout()
    fig.savefig(out / "dam_break_pressure.png", dpi=100)
    plt.close(fig)
    return metrics


# MARIN's dam break against a box (Kleefsman et al. 2005; SPHERIC benchmark test 2;
# configs/dam_break_obstacle.toml): the four gauges' measured water heights, copied down-sampled from
# the record Lethe's example carries (the file's header names the source and the columns' order)
MARIN_DATA = Path(__file__).resolve().parent / "data" / "marin_2005_heights.csv"
MARIN_GAUGES = ("H1", "H2", "H3", "H4")
HEIGHT_TOLERANCE = 0.15  # the issue's target for peak and impulse at each probe
# The window of every measure: the first 6 s after the release, the span SPHERIC's test 2 gives its
# results over (the record goes on to 7.38 s)
MARIN_END_S = 6.0
# The reservoir gauge H4 starts at its peak (the still column, 0.55 m); its measured peak is the
# returning wave's, after the reservoir's lowest level in the record (0.102 m at 2.56 s)
MARIN_H4_RETURN_S = 2.56


# The pressure on the box's front face, P1-P4 (launch/data/marin_2005_pressure.csv, its header: the
# source, the rows copied): peak and impulse over the first impact and the second after it, a window
# fixed from the record alone: from before the surge reaches P1 (0.393 s) over the impact peaks
# (0.415-0.459 s) and the decay to the plateau, to the end of the rows copied. Both signals are
# filtered by the Buchner case's moving average (PRESSURE_FILTER_S, 10 ms) for the peak: the record
# has the sensors' noise (+-50-90 Pa at rest, spikes of 1-2 kPa at the peak), the simulation the
# fluid's acoustic noise; the impulse is of the signals as sampled
MARIN_PRESSURE_DATA = Path(__file__).resolve().parent / "data" / "marin_2005_pressure.csv"
MARIN_SENSORS = ("P1", "P2", "P3", "P4")
MARIN_PRESSURE_WINDOW = (0.35, 1.40)


def load_record(path: Path, names, unit: str) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """A measured record as launch/data keeps it (``#`` comment lines, then the header
    ``t_s,<name>_<unit>,...`` and one row per sample): (t in s, {name: column}), in increasing t."""
    lines = [line for line in Path(path).read_text().splitlines() if line.strip() and not line.startswith("#")]
    header = "t_s," + ",".join(f"{name}_{unit}" for name in names)
    if lines[0] != header:
        raise ValueError(f"{path}: header {lines[0]!r}, expected {header!r}")
    table = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
    if not np.all(np.diff(table[:, 0]) > 0.0):
        raise ValueError(f"{path}: the times do not increase")
    return table[:, 0], {name: table[:, 1 + k] for k, name in enumerate(names)}


def load_marin_pressure(path: Path = MARIN_PRESSURE_DATA) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The experiment's pressure record: (t in s, {sensor: pressure in Pa}), in increasing t."""
    return load_record(path, MARIN_SENSORS, "Pa")


def pressure_measures(t, p) -> tuple[float, float, float, float, float]:
    """(peak of the PRESSURE_FILTER_S moving average, its time, raw peak, its time, impulse: the
    integral of p dt) of one sensor's record over MARIN_PRESSURE_WINDOW."""
    lo, hi = MARIN_PRESSURE_WINDOW
    peak, when, _ = peak_and_impulse(t, moving_average(t, p, PRESSURE_FILTER_S), lo, hi)
    raw, raw_when, impulse = peak_and_impulse(t, p, lo, hi)
    return peak, when, raw, raw_when, impulse


# A sensor's rise: the first time it reads more than this (the note gives it beside the record's, the
# timing that neither measure scores)
MARIN_RISE_PA = 1000.0


def rise_time(t, p, level: float = MARIN_RISE_PA) -> float:
    """The first time a signal exceeds ``level`` (nan: never): a sensor's rise, a gauge's arrival."""
    above = np.flatnonzero(np.nan_to_num(np.asarray(p, dtype=float)) > level)
    return float(np.asarray(t, dtype=float)[above[0]]) if above.size else float("nan")


def load_marin(path: Path = MARIN_DATA) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The experiment's record: (t in s, {gauge: height in m}), in increasing t."""
    return load_record(path, MARIN_GAUGES, "m")


def highest(gauge: str) -> str:
    """The probe that reads ``gauge``'s line by its highest wet point (the raw figure, which spray sets)."""
    return f"{gauge}_highest"


def height_measures(t, h, gauge: str) -> tuple[float, float, float, float]:
    """(peak height, its time, impulse: the integral of h dt, arrival: the first time h exceeds
    0.02 m) of one gauge's record over [0, MARIN_END_S] (the reservoir's H4: its peak after
    MARIN_H4_RETURN_S). A dry gauge (nan: no water on its line) reads 0."""
    t, h = np.asarray(t, dtype=float), np.nan_to_num(np.asarray(h, dtype=float), nan=0.0)
    peak, when, impulse = peak_and_impulse(t, h, 0.0, MARIN_END_S)
    if gauge == "H4":
        peak, when, _ = peak_and_impulse(t, h, MARIN_H4_RETURN_S, MARIN_END_S)
    return peak, when, impulse, rise_time(t, h, 0.02)


def dam_break_obstacle(quick: bool, out: Path, backend: str = "cpu", opts: CaseOptions | None = None) -> list[Metric]:
    """MARIN's 3D dam break against a box (configs/dam_break_obstacle.toml): the water height at the
    four gauges against the measured records over the first MARIN_END_S, each gauge's peak (H4: the
    returning wave's) and impulse (the integral of h dt), the arrival time in the note."""
    opts = opts or CaseOptions(backend)
    config = CONFIGS / "dam_break_obstacle.toml"
    scene = load_scene(config, list(opts.overrides))  # quick: the file's own H0 / 15, so that sph run gives its bits
    H0 = scene.fluid.blocks[0].max[1] - scene.fluid.blocks[0].min[1]
    if opts.dx or not quick:
        scene = load_scene(config, [f"particles.spacing={opts.dx or H0 / 25!r}", *opts.overrides])
    dx = scene.particles.spacing
    t_exp, h_exp = load_marin()
    sim = Simulation(scene, opts.precision, opts.backend)
    names = sim.probes.names
    clock = _Clock(sim, opts, "dam_break_obstacle", MARIN_END_S)
    rec = probe_record(sim, MARIN_END_S, clock)
    clock.done()
    t_sim = rec[:, 0]  # the first sample after output.probes_every steps; the measures hold it back to t = 0
    metrics, found = [], {}
    for gauge in MARIN_GAUGES:
        k = names.index(gauge)
        h_sim = rec[:, 1 + k]
        found[gauge] = h_sim
        peak, when, impulse, arrival = height_measures(t_sim, h_sim, gauge)
        peak_e, when_e, impulse_e, arrival_e = height_measures(t_exp, h_exp[gauge], gauge)
        x = scene.probes[k].at[0]
        which = "the returning wave's peak" if gauge == "H4" else "peak"
        top = highest(gauge)
        raw = ""
        if top in names:
            found[top] = rec[:, 1 + names.index(top)]
            peak_top, when_top, impulse_top, _ = height_measures(t_sim, found[top], gauge)
            raw = (f"; raw, the line's highest wet point: {peak_top:.3f} m at {when_top:.2f} s, "
                   f"impulse {impulse_top:.4f} m s")
        metrics.append(Metric(f"dam_break_obstacle.{gauge}_peak_relative", abs(peak / peak_e - 1.0), HEIGHT_TOLERANCE,
                              f"{which} {peak:.3f} m at {when:.2f} s vs MARIN {peak_e:.3f} m at {when_e:.2f} s; "
                              f"x = {x:g} m, a wire gauge{raw}", quantity=peak, reference=peak_e))
        metrics.append(Metric(f"dam_break_obstacle.{gauge}_impulse_relative", abs(impulse / impulse_e - 1.0),
                              HEIGHT_TOLERANCE,
                              f"integral of h dt over 0-{MARIN_END_S:g} s {impulse:.4f} vs MARIN {impulse_e:.4f} m s"
                              + ("" if gauge == "H4" else f"; wet (h > 0.02 m) from {arrival:.3f} s vs {arrival_e:.3f} s")
                              + (f"; {sim.n_particles} particles, H0 / {H0 / dx:.0f}" if gauge == "H1" else ""),
                              quantity=impulse, reference=impulse_e))
    t_pe, p_exp = load_marin_pressure()
    lo, hi = MARIN_PRESSURE_WINDOW
    for sensor in MARIN_SENSORS:
        k = names.index(sensor)
        found[sensor] = rec[:, 1 + k]
        peak, when, raw, raw_when, impulse = pressure_measures(t_sim, found[sensor])
        peak_e, when_e, raw_e, raw_when_e, impulse_e = pressure_measures(t_pe, p_exp[sensor])
        y = scene.probes[k].at[1]
        metrics.append(Metric(f"dam_break_obstacle.{sensor}_peak_relative", abs(peak / peak_e - 1.0), HEIGHT_TOLERANCE,
                              f"{1e3 * PRESSURE_FILTER_S:g} ms moving average {peak:.0f} Pa at {when:.3f} s vs MARIN "
                              f"{peak_e:.0f} Pa at {when_e:.3f} s; raw {raw:.0f} Pa at {raw_when:.3f} s vs "
                              f"{raw_e:.0f} Pa at {raw_when_e:.3f} s; the box's face, {y:g} m up",
                              quantity=peak, reference=peak_e))
        metrics.append(Metric(f"dam_break_obstacle.{sensor}_impulse_relative", abs(impulse / impulse_e - 1.0),
                              HEIGHT_TOLERANCE,
                              f"integral of p dt over {lo:g}-{hi:g} s {impulse:.1f} vs MARIN {impulse_e:.1f} Pa s; "
                              f"rises past {MARIN_RISE_PA:g} Pa at {rise_time(t_sim, found[sensor]):.3f} s vs "
                              f"{rise_time(t_pe, p_exp[sensor]):.3f} s",
                              quantity=impulse, reference=impulse_e))
    opts.stats.update(probes_t=t_sim.tolist(), probes={g: h.tolist() for g, h in found.items()})
    if not opts.plot:
        return metrics
    plt = _plot()
    fig, axes = plt.subplots(2, 2, figsize=(12, 7), sharex=True)
    for ax, gauge in zip(axes.ravel(), MARIN_GAUGES):
        k = names.index(gauge)
        ax.plot(t_exp, h_exp[gauge], "k-", lw=1.2, label="MARIN (Kleefsman et al. 2005)")
        if highest(gauge) in found:
            ax.plot(t_sim, np.nan_to_num(found[highest(gauge)], nan=0.0), "-", color="0.6", lw=0.6,
                    label="sphfluid, the line's highest wet point (raw: spray sets it)")
        ax.plot(t_sim, np.nan_to_num(found[gauge], nan=0.0), "-", color="C3", lw=1.0,
                label=f"sphfluid, H0 / {H0 / dx:.0f} ({sim.n_particles:,} particles), a wire gauge")
        ax.set_xlim(0.0, MARIN_END_S)
        ax.set_ylim(0.0, 0.7)
        ax.set_title(f"{gauge}, x = {scene.probes[k].at[0]:g} m")
        ax.set_ylabel("water height (m)")
        ax.legend(fontsize=8, loc="upper right")
    _save_panels(plt, fig, axes, "water heights", out / "dam_break_obstacle.png")
    fig, axes = plt.subplots(2, 2, figsize=(12, 7), sharex=True)
    for ax, sensor in zip(axes.ravel(), MARIN_SENSORS):
        k = names.index(sensor)
        ax.axvspan(lo, hi, color="0.93", label="window (metrics)")
        ax.plot(t_pe, p_exp[sensor], "-", color="0.6", lw=0.5, label="MARIN (Kleefsman et al. 2005), 1 kHz")
        ax.plot(t_pe, moving_average(t_pe, p_exp[sensor], PRESSURE_FILTER_S), "k-", lw=1.2,
                label=f"MARIN, {1e3 * PRESSURE_FILTER_S:g} ms moving average")
        ax.plot(t_sim, found[sensor], "-", color="C0", lw=0.5, alpha=0.6, label="sphfluid, raw probe")
        ax.plot(t_sim, moving_average(t_sim, found[sensor], PRESSURE_FILTER_S), "-", color="C3", lw=1.2,
                label=f"sphfluid, H0 / {H0 / dx:.0f}, {1e3 * PRESSURE_FILTER_S:g} ms moving average")
        ax.set_xlim(0.25, 1.5)
        ax.set_title(f"{sensor}, {scene.probes[k].at[1]:g} m up the box's face")
        ax.set_ylabel("pressure (Pa)")
        ax.legend(fontsize=7, loc="upper right")
    _save_panels(plt, fig, axes, "pressure on the box's face", out / "dam_break_obstacle_pressure.png")
    return metrics


def _save_panels(plt, fig, axes, what: str, path: Path):
    """Label the time axes of a MARIN figure's 2 x 2 panels, title it and write it to ``path``."""
    for ax in axes[1]:
        ax.set_xlabel("t (s)")
    fig.suptitle(f"3D dam break against a box (SPHERIC test 2): {what}")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def channel_velocity(y, U: float, D: float):
    """Plane Poiseuille flow of mean velocity U between plates at y = 0 and y = D."""
    return 6.0 * U * (y / D) * (1.0 - y / D)


def channel(quick: bool, out: Path, backend: str = "cpu", opts: CaseOptions | None = None) -> list[Metric]:
    """Developing channel flow between a velocity inlet and a pressure outlet (configs/channel_2d.toml,
    Re = 10): from 2.5 D downstream of the inlet (the laminar entry length is ~(0.6 + 0.05 Re) D),
    the time-averaged velocity profile against plane Poiseuille's parabola, the section's flux
    against the inlet's U D, and the outlets' removals against the inlet's additions over the
    averaging window (a steady state neither fills nor drains the channel)."""
    opts = opts or CaseOptions(backend)
    scene = load_scene(CONFIGS / "channel_2d.toml", [*(() if opts.dx is None and quick else
                                                       (f"particles.spacing={opts.dx or 2.5e-4}",)), *opts.overrides])
    bottom, top = scene.domain.planes
    D, U, dx = top.point[1] - bottom.point[1], scene.inlets[0].velocity[0], scene.particles.spacing
    x_lo, x_hi = 2.5 * D, scene.outlets[0].min[0] - scene.sph.support * dx  # clear of the outlet's support
    t_avg, t_end, every = 4.0, 6.0, 0.05   # 6 s: the fluid has crossed the channel once
    sim = Simulation(scene, opts.precision, opts.backend)
    clock = _Clock(sim, opts, "channel", t_end)
    bins = 10
    u_sum, exact_sum, count = np.zeros(bins), np.zeros(bins), np.zeros(bins)
    fluxes, counts_at = [], {}
    t_next = t_avg
    while sim.t < t_end - 1e-12:
        sim.step(dt_cap=min(t_next, t_end) - sim.t)
        clock.tick()
        if sim.t < t_next - 1e-12:
            continue
        counts_at[round(sim.t, 6)] = (sim.open.inflow, sim.open.outflow)
        t_next += every
        s = sim.state
        n = s.n_owned
        x, u = s.x[:n].astype(np.float64), sim.synchronised_velocity()[:n, 0].astype(np.float64)
        sel = (x[:, 0] >= x_lo) & (x[:, 0] < x_hi)
        y = x[sel, 1] - bottom.point[1]
        k = np.clip((y / D * bins).astype(int), 0, bins - 1)
        np.add.at(u_sum, k, u[sel])
        np.add.at(exact_sum, k, channel_velocity(y, U, D))
        np.add.at(count, k, 1.0)
        volume = (s.m[:n] / s.rho[:n]).astype(np.float64)[sel]
        fluxes.append(float(np.sum(u[sel] * volume)) / (x_hi - x_lo))
    clock.done()
    u_mean, u_exact = u_sum / np.maximum(count, 1), exact_sum / np.maximum(count, 1)
    u_max = 1.5 * U
    rms = float(np.sqrt(np.mean((u_mean - u_exact) ** 2))) / u_max
    flux = float(np.mean(fluxes)) / (U * D)
    (in0, out0), (in1, out1) = counts_at[min(counts_at)], counts_at[max(counts_at)]
    balance = abs((out1 - out0) - (in1 - in0)) / max(in1 - in0, 1)
    window = f"t = {t_avg:g}..{t_end:g} s, x = {x_lo / D:.2f}..{x_hi / D:.2f} D, {round(D / dx)} across"
    metrics = [Metric("channel.profile_rms_of_u_max", rms, 0.03, f"{bins} bins across, {window}"),
               Metric("channel.flux_error_of_U_D", abs(flux - 1.0), 0.02, f"flux {flux:.4f} U D, {window}"),
               Metric("channel.outflow_minus_inflow", balance, 0.02,
                      f"{in1 - in0} particles in, {out1 - out0} out over t = {t_avg:g}..{t_end:g} s")]
    if not opts.plot:
        return metrics
    plt = _plot()
    fig, ax = plt.subplots(figsize=(6, 4))
    yy = np.linspace(0.0, D, 200)
    ax.plot(yy / D, channel_velocity(yy, U, D) / U, "-", color="k", lw=1, label="plane Poiseuille")
    ax.plot((np.arange(bins) + 0.5) / bins, u_mean / U, "o", color="C0", label=f"sphfluid, {window}")
    s = sim.state
    n = s.n_owned
    near = s.x[:n, 0] < scene.inlets[0].max[0] + 0.5 * D
    ax.plot((s.x[:n, 1][near] - bottom.point[1]) / D, sim.synchronised_velocity()[:n, 0][near] / U, ".", ms=2,
            color="C1", label="particles within D / 2 of the inlet, last step")
    ax.set_xlabel("y / D")
    ax.set_ylabel("u / U")
    ax.legend(fontsize=7)
    ax.set_title("Developing channel flow, Re = 10: inlet plug to parabola")
    fig.tight_layout()
    fig.savefig(out / "channel.png", dpi=100)
    plt.close(fig)
    return metrics


def circular_couette_velocity(r, omega: float, r1: float, r2: float):
    """Steady azimuthal velocity between a cylinder of radius r1 turning at omega and a fixed one of r2."""
    A = -omega * r1 ** 2 / (r2 ** 2 - r1 ** 2)
    B = omega * r1 ** 2 * r2 ** 2 / (r2 ** 2 - r1 ** 2)
    return A * r + B / r


def circular_couette(quick: bool, out: Path, backend: str = "cpu", opts: CaseOptions | None = None) -> list[Metric]:
    """Circular Couette flow (configs/circular_couette_2d.toml): an inner cylinder turning (a rotating
    obstacle, sphcore/motion.py) inside a fixed one, from rest to t = 3 s (30 x the slowest mode's
    time constant (R2 - R1)^2 / (pi^2 nu)); the mean azimuthal velocity in 10 rings across the gap
    against A r + B / r, in units of the rim speed Omega R1: the largest error over all rings, and
    over the inner half (where the turning wall drives the flow)."""
    opts = opts or CaseOptions(backend)
    dx = opts.dx or (5.0e-5 if quick else 2.5e-5)
    scene = load_scene(CONFIGS / "circular_couette_2d.toml", [f"particles.spacing={dx}", *opts.overrides])
    inner = scene.obstacles[0]
    omega, r1, r2 = math.radians(inner.angular_velocity[2]), inner.radius, scene.domain.radius
    centre = np.array(inner.center)
    sim = Simulation(scene, opts.precision, opts.backend)
    t_end = 3.0
    clock = _Clock(sim, opts, "circular_couette", t_end)
    while sim.t < t_end - 1e-12:
        sim.step(dt_cap=t_end - sim.t)
        clock.tick()
    clock.done()
    n = sim.state.n_owned
    rel = sim.state.x[:n].astype(np.float64) - centre
    v = sim.synchronised_velocity()[:n].astype(np.float64)
    r = np.hypot(rel[:, 0], rel[:, 1])
    u = (rel[:, 0] * v[:, 1] - rel[:, 1] * v[:, 0]) / r
    rings = 10
    k = np.clip(((r - r1) / (r2 - r1) * rings).astype(int), 0, rings - 1)
    U = omega * r1
    mean = np.array([u[k == b].mean() for b in range(rings)])
    exact = np.array([circular_couette_velocity(r[k == b], omega, r1, r2).mean() for b in range(rings)])
    error = np.abs(mean - exact) / U
    gap_out = (r2 - r.max()) / dx
    note = f"t = {t_end:g} s, {n} particles, {round((r2 - r1) / dx)} across"
    metrics = [Metric("circular_couette.velocity_error_of_U", float(error.max()), 0.03,
                      f"largest of {rings} rings, {note}; the outermost particle {gap_out:.2f} dx from the outer wall"),
               Metric("circular_couette.inner_half_error_of_U", float(error[: rings // 2].max()), 0.03,
                      f"the {rings // 2} rings nearest the turning cylinder")]
    if not opts.plot:
        return metrics
    plt = _plot()
    fig, ax = plt.subplots(figsize=(6, 4))
    rr = np.linspace(r1, r2, 200)
    ax.plot(rr / r1, circular_couette_velocity(rr, omega, r1, r2) / U, "k-", lw=1, label="A r + B / r")
    ax.plot(r / r1, u / U, ".", ms=1, color="C1", alpha=0.4, label="particles")
    ax.plot((r1 + (np.arange(rings) + 0.5) * (r2 - r1) / rings) / r1, mean / U, "o", color="C0", label="ring means")
    ax.set_xlabel("r / R1")
    ax.set_ylabel("u_theta / (Omega R1)")
    ax.legend(fontsize=8)
    ax.set_title(f"Circular Couette flow, a turning inner cylinder ({note})", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "circular_couette.png", dpi=100)
    plt.close(fig)
    return metrics




def water_wavenumber(omega: float, depth: float, g: float) -> float:
    """k (1/m) of the linear dispersion relation omega^2 = g k tanh(k d), by bisection (the left
    side grows with k)."""
    lo, hi = 0.0, 10.0 * omega * omega / g + 10.0 / depth
    for _ in range(200):
        k = 0.5 * (lo + hi)
        lo, hi = (k, hi) if g * k * math.tanh(k * depth) < omega * omega else (lo, k)
    return 0.5 * (lo + hi)


def piston_height_per_stroke(kd: float) -> float:
    """H / S of a piston wave maker's progressive wave, linear theory (Biesel & Suquet 1951; Dean &
    Dalrymple 1991, eq. 6.19): 2 (cosh 2kd - 1) / (sinh 2kd + 2kd)."""
    return 2.0 * (math.cosh(2.0 * kd) - 1.0) / (math.sinh(2.0 * kd) + 2.0 * kd)


def harmonic(t, eta, omega: float, harmonics: int = 2) -> tuple[float, float]:
    """Amplitude and phase phi of the first harmonic of eta(t) (eta ~ A cos(omega t - phi)), by least
    squares on a mean, cos(n omega t) and sin(n omega t) for n = 1..harmonics over whole periods: a
    gauge's noise and the wave's higher harmonics (a steeper crest than trough) do not enter A."""
    t, eta = np.asarray(t), np.asarray(eta)
    columns = [np.ones_like(t)]
    for n in range(1, harmonics + 1):
        columns += [np.cos(n * omega * t), np.sin(n * omega * t)]
    coef = np.linalg.lstsq(np.stack(columns, axis=1), eta, rcond=None)[0]
    return float(math.hypot(coef[1], coef[2])), float(math.atan2(coef[2], coef[1]))


@dataclass(frozen=True)
class PistonWave:
    """What linear theory says of a scene's piston wave maker (its one plane with a frequency)."""
    depth: float    # d (m): the still water's depth, the first block's height
    period: float   # T (s)
    omega: float    # 2 pi / T (1/s)
    k: float        # wavenumber (1/m), the dispersion relation's
    stroke: float   # S (m): twice the piston's amplitude along x
    height: float   # H (m) = S H/S(kd)

    @classmethod
    def of(cls, scene) -> "PistonWave":
        piston = next(p for p in scene.domain.planes if p.frequency > 0.0)
        depth = scene.fluid.blocks[0].max[1] - scene.fluid.blocks[0].min[1]
        omega = 2.0 * math.pi * piston.frequency
        k = water_wavenumber(omega, depth, abs(scene.forces.gravity[1]))
        stroke = 2.0 * abs(piston.amplitude[0])
        return cls(depth, 1.0 / piston.frequency, omega, k, stroke, stroke * piston_height_per_stroke(k * depth))


def probe_record(sim, t_end: float, clock=None) -> np.ndarray:
    """Run ``sim`` to ``t_end`` and return its probes' samples, one row (t, value per probe) each."""
    rows = []
    while sim.t < t_end - 1e-12:
        sim.step(dt_cap=t_end - sim.t)
        if clock is not None:
            clock.tick()
        rows += [(t, *values) for _, t, values in sim.probes.take_samples()]
    return np.array(rows)


# The wave-maker's window, in periods of the piston: from 3 T (the wave train's front, moving at the
# group speed 0.66 m/s, has passed the far gauge by 1.1 T and the piston's start-up by ~2 T more) to
# 7 T (whole periods for the harmonic fit). Chosen when the flume ended in a bare wall, whose
# reflection of the start's long-wave precursors (at up to sqrt(g d)) came back inside it; since
# 2026-12-05 the flume's far half is a damping zone that takes the waves in (configs/wave_maker_2d.toml)
# and the window is unchanged
WAVE_WINDOW_T = (3.0, 7.0)


def incident_and_reflected(fits, gauges, k: float) -> tuple[float, float]:
    """Amplitudes (m) of the wave running along +x and of the one coming back, from two or more
    gauges' first harmonics (``harmonic``'s (amplitude, phase) at x_j): eta_j = Re(Z_j e^{i omega t})
    with Z_j = a_i e^{-i k x_j} + a_r e^{i k x_j} (Goda & Suzuki 1976; least squares beyond two gauges;
    no two gauges k (x2 - x1) near a multiple of pi apart)."""
    z = np.array([a * np.exp(-1j * phase) for a, phase in fits])
    x = np.asarray(gauges, dtype=float)
    (a_i, a_r), *_ = np.linalg.lstsq(np.stack([np.exp(-1j * k * x), np.exp(1j * k * x)], axis=1), z, rcond=None)
    return float(abs(a_i)), float(abs(a_r))


def wave_maker(quick: bool, out: Path, backend: str = "cpu", opts: CaseOptions | None = None) -> list[Metric]:
    """A piston wave maker (configs/wave_maker_2d.toml): at two gauges the first harmonic's wave
    height over WAVE_WINDOW_T against linear wave-maker theory (H = S H/S(kd)), and the phase speed
    from its phase difference between the gauges, k (x2 - x1), against omega / k."""
    opts = opts or CaseOptions(backend)
    dx = opts.dx or (0.1 / 15 if quick else 0.1 / 30)  # 15 or 30 spacings over the depth
    scene = load_scene(CONFIGS / "wave_maker_2d.toml", [f"particles.spacing={dx}", *opts.overrides])
    wave = PistonWave.of(scene)
    depth, period, omega, k, stroke, height = (wave.depth, wave.period, wave.omega, wave.k, wave.stroke,
                                               wave.height)
    speed = omega / k
    names = [p.name for p in scene.probes]
    gauges = [p.at[0] for p in scene.probes]
    sim = Simulation(scene, opts.precision, opts.backend)
    t_end = WAVE_WINDOW_T[1] * period
    clock = _Clock(sim, opts, "wave_maker", t_end)
    rec = probe_record(sim, t_end, clock)
    clock.done()
    t = rec[:, 0]
    inside = t >= WAVE_WINDOW_T[0] * period - 1e-9
    etas = [rec[:, 1 + j] - depth for j in range(len(names))]  # the surface's elevation above still water
    fits = [harmonic(t[inside], eta[inside], omega) for eta in etas]
    measured = [2.0 * amplitude for amplitude, _ in fits]
    errors = [abs(h / height - 1.0) for h in measured]
    for name, x, h in zip(names, gauges, measured):
        log.info("wave_maker: %s (x = %g m): first-harmonic wave height %.4f m", name, x, h)
    shift = (fits[1][1] - fits[0][1]) % (2.0 * math.pi)  # k (x2 - x1) for a wave running along +x
    c_sim = omega * (gauges[1] - gauges[0]) / shift
    a_in, a_back = incident_and_reflected(fits[:2], gauges[:2], k)  # what the damping zone sends back
    metrics = [Metric("wave_maker.height_relative", max(errors), 0.15 if quick else 0.10,
                      f"largest of {len(names)} gauges: first-harmonic H = {', '.join(f'{h * 100:.2f}' for h in measured)} cm "
                      f"against {100 * height:.2f} cm (S = {100 * stroke:g} cm, kd = {k * depth:.3f}), "
                      f"{sim.n_particles} particles, {depth / scene.particles.spacing:.0f} over the depth"),
               Metric("wave_maker.phase_speed_relative", abs(c_sim / speed - 1.0), 0.05,
                      f"c = omega (x2 - x1) / (phase difference) = {c_sim:.3f} m/s against omega / k = {speed:.3f} m/s; "
                      f"diagnostic: reflected / incident amplitude {a_back / a_in:.3f} (Goda & Suzuki, the 2 gauges)")]
    opts.stats.update(wave_heights=measured, phase_speed=c_sim, reflection=a_back / a_in)
    if not opts.plot:
        return metrics
    plt = _plot()
    fig, ax = plt.subplots(figsize=(7, 4))
    for j, name in enumerate(names):
        ax.plot(t / period, etas[j] / height, lw=0.8, color=f"C{j}",
                label=f"{name}, x = {gauges[j]:g} m: first harmonic H = {measured[j] * 100:.2f} cm")
        tw = t[inside]
        ax.plot(tw / period, fits[j][0] * np.cos(omega * tw - fits[j][1]) / height, "--", lw=1.2, color=f"C{j}")
    for sign in (-0.5, 0.5):
        ax.axhline(sign, color="k", lw=0.6, ls="--")
    ax.axvspan(*WAVE_WINDOW_T, color="0.9", zorder=0, label="measured window")
    ax.set_xlabel("t / T")
    ax.set_ylabel("surface elevation / H of linear theory")
    ax.legend(fontsize=8, loc="lower left")
    ax.set_title(f"Piston wave maker: kd = {k * depth:.2f}, linear theory H = {100 * height:.2f} cm (dashed: +-H/2)")
    fig.tight_layout()
    fig.savefig(out / "wave_maker.png", dpi=100)
    plt.close(fig)
    return metrics


CASES = {"hydrostatic": hydrostatic, "hydrostatic_3d": hydrostatic_3d, "dam_break": dam_break, "dam_break_3d": dam_break_3d,
         "taylor_green": taylor_green, "oscillating_drop": oscillating_drop, "poiseuille": poiseuille,
         "couette": couette, "floating_box": floating_box, "floating_square": floating_square,
         "settling_cylinder": settling_cylinder, "settling_cylinder_closed": settling_cylinder_closed,
         "hydrostatic_probes": hydrostatic_probes,
         "cavity": cavity, "dam_break_pressure": dam_break_pressure, "channel": channel,
         "circular_couette": circular_couette, "wave_maker": wave_maker, "dam_break_obstacle": dam_break_obstacle}


# Orders of the same sums (``sph validate --orders K``): the case as configured, then the neighbour
# lists' skin and the grid's cells varied. Each changes the order in which every particle's sums are
# added and nothing else (the same neighbours, the same model), so what differs between them is
# rounding, amplified by the flow: a chaotic read-out such as the dam-break front's late speed moves
# by several per cent with it (docs/VALIDATION.md). Orders a scene refuses (a skin on the GPU, or one
# that a short periodic axis cannot hold) or that resolve to one already run (the automatic skin is 0
# on the GPU: RepeatedOrder, raised before the first step) are left out.
ORDERS = ((), ("run.neighbour_skin=0",), ("run.cells_per_support=1",),
          ("run.neighbour_skin=0", "run.cells_per_support=1"), ("run.neighbour_skin=0.1",),
          ("run.neighbour_skin=0.1", "run.cells_per_support=1"), ("run.neighbour_skin=0.3",),
          ("run.neighbour_skin=0.3", "run.cells_per_support=1"))
ORDER_KEYS = tuple(dict.fromkeys(o.split("=", 1)[0] for order in ORDERS for o in order))  # the keys they vary
# Cases run in several orders unless --orders says otherwise: the 2D dam break's front is a chaotic
# read-out (its late speed moves by 1-2 % with the rounding alone, its RMS straddled the full case's
# 3 % target: docs/VALIDATION.md), and four orders halve the error of its mean for ~4x a run (under
# 2 minutes in all, full). The 3D case (8 minutes a run) and every other case run once.
CASE_ORDERS = {"dam_break": 4}


def case_orders(name: str, orders: int | None) -> int:
    """How many orders case ``name`` runs in: ``orders`` (--orders), or its own (CASE_ORDERS, else 1)."""
    return CASE_ORDERS.get(name, 1) if orders is None else orders


def run_orders(name: str, quick: bool, out: Path, backend: str, overrides: tuple, orders: int,
               dx: float | None = None) -> list[Metric]:
    """Case ``name`` in up to ``orders`` distinct orders of its sums (ORDERS); each metric becomes its
    mean over them (a relative metric with a quantity: the mean quantity against the reference), its
    note the spread and every order's figure. The first order's run draws the case's plot; the spread
    is drawn in OUT/<name>_orders.png. ``dx``: another spacing than the case's (a study; CaseOptions)."""
    runs, left_out = [], []  # (order, its metrics); 'order: why it was not counted'
    done = {}  # resolved (skin, cells per support) -> the order that ran it (checked before a run steps)
    for order in ORDERS:
        if len(runs) == orders:
            break
        label = " ".join(order) or "as configured"
        log.info("%s (%s), order %d of %d: %s", name, "quick" if quick else "full", len(runs) + 1, orders, label)
        opts = CaseOptions(backend, dx=dx, overrides=(*order, *overrides), plot=not runs, orders_run=done)
        try:
            metrics = CASES[name](quick, out, backend, opts)
        except (SceneError, RepeatedOrder) as e:
            if not order:
                raise  # the case itself: the user's overrides
            left_out.append(f"{label}: {e}")
            log.info("%s: order %s left out: %s", name, label, e)
            continue
        done[opts.stats["sums_order"]] = label
        runs.append((label, metrics))
    combined = [_combined(m.name, [x for _, ms in runs for x in ms if x.name == m.name], orders) for m in runs[0][1]]
    if len(runs) < orders:
        log.warning("%s: %d of the %d orders asked for ran; left out: %s", name, len(runs), orders, "; ".join(left_out))
    _plot_orders(name, runs, combined, out)
    return combined


def _spread(values, fmt: str) -> str:
    v = np.asarray(values, dtype=float)
    return (f"{fmt.format(v.mean())} ({fmt.format(v.min())}-{fmt.format(v.max())}, sd "
            f"{fmt.format(v.std(ddof=1) if v.size > 1 else 0.0)})")


def _combined(name: str, group: list[Metric], asked: int) -> Metric:
    """One metric from its runs in several orders (run_orders)."""
    first = group[0]
    values = [m.value for m in group]
    quantities = [m.quantity for m in group]
    k = len(group)
    each = ", ".join(f"{v:.4g}" for v in values)
    of = f"{k} orders of the sums" + (f" ({asked} asked; the others left out, logged)" if k < asked else "")
    if all(math.isfinite(q) for q in quantities) and math.isfinite(first.reference) and first.reference != 0.0:
        q = float(np.mean(quantities))
        value = abs(q / first.reference - 1.0)
        head = (f"the mean over {of}: {_spread(quantities, '{:.4g}')} against {first.reference:.4g}; each order's "
                f"metric {each}")
        quantity = q
    else:
        value = float(np.mean(values))
        head = f"the mean over {of}: {_spread(values, '{:.4g}')}; each {each}"
        quantity = float("nan")
    if min(values) <= first.tolerance < max(values):
        head += "; the orders straddle the tolerance"
    elif min(values) > first.tolerance and value <= first.tolerance:
        head += "; each order alone misses the tolerance"
    return Metric(name, value, first.tolerance, f"{head}; first order: {first.note}", quantity, first.reference)


def _order_label(label: str) -> str:
    """'run.neighbour_skin=0 run.cells_per_support=1' -> 'skin 0, cells of H' (the plot's axis)."""
    names = {"run.neighbour_skin": "skin {}", "run.cells_per_support": "cells of H/{}"}
    parts = [names[key].format(value) for key, value in (o.split("=", 1) for o in label.split() if "=" in o)]
    return ", ".join(parts).replace("cells of H/1", "cells of H") if parts else label


def _plot_orders(name: str, runs: list, combined: list[Metric], out: Path):
    """Each metric's value in every order (dots), the combined value (the line; the mean, or for a
    relative metric the mean quantity's error) and the tolerance (dashed)."""
    plt = _plot()
    fig, axes = plt.subplots(len(combined), 1, figsize=(6.5, 1.2 + 1.5 * len(combined)), squeeze=False)
    for ax, m in zip(axes[:, 0], combined):
        values = [next((x.value for x in ms if x.name == m.name), float("nan")) for _, ms in runs]
        ax.plot(values, range(len(values)), "o", color="C0", label="each order")
        ax.axvline(m.value, color="C0", label="combined")
        ax.axvline(m.tolerance, color="k", ls="--", lw=1, label="tolerance")
        ax.set_yticks(range(len(runs)), [_order_label(label) for label, _ in runs], fontsize=7)
        ax.set_ylim(-0.6, len(runs) - 0.4)
        ax.set_title(f"{m.name}: {m.value:.4g} ({'PASS' if m.passed else 'FAIL'}; tolerance {m.tolerance:g})",
                     fontsize=9)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize=8, frameon=False)
    fig.suptitle(f"{name}: one model, its sums added in {len(runs)} orders", fontsize=10)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    fig.savefig(out / f"{name}_orders.png", dpi=100)
    plt.close(fig)


def run_validate(names: list[str], quick: bool, out: Path, backend: str = "cpu", overrides: tuple = (),
                 orders: int | None = None) -> int:
    """Run the named cases; ``overrides`` (--set strings) apply to every case's scene; ``orders`` > 1
    runs each case in that many orders of its sums (run_orders); None: the case's own (CASE_ORDERS)."""
    out.mkdir(parents=True, exist_ok=True)
    failed = 0
    print(f"{'metric':<34} {'value':>10} {'tolerance':>10} result")
    if overrides:
        print(f"scene overrides: {' '.join(overrides)}")
    for name in names:
        k = case_orders(name, orders)
        if k > 1:
            metrics = run_orders(name, quick, out, backend, tuple(overrides), k)
        else:
            log.info("%s (%s)", name, "quick" if quick else "full")
            metrics = CASES[name](quick, out, backend, CaseOptions(backend, overrides=overrides))
        for m in metrics:
            print(m.line(), flush=True)
            failed += not m.passed
    print(f"plots in {out}/")
    return 1 if failed else 0
