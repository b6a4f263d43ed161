"""The prototype of the traction force (physics/traction.py), as it was measured on 2026-12-06
before it was built: the closed settling cylinder with the body's force from a surface integral
computed here in numpy each step, in place of the reaction, on the uncorrected difference form.

It ran on a checkout of 03e6cf4 with difference_form.patch applied (``git apply --3way``; the
scene.py hunk conflicts with the hydrostatic keys: keep both sides), from that checkout's root:

    python traction_prototype.py --set 'sph.pressure_gradient="difference"' --set terms.shifting=2.0 \
        --force surface [--interp mls] [--viscous surface]

The pressure at 256 points on the circle is a Shepard sum (default) or a linear least-squares fit
(``--interp mls``) of the particles within H; the viscous force is the reaction's (its part at
p = 0) or, with ``--viscous surface``, mu (grad u + grad u^T) n from a fit of v - U without a
constant. Measured (quick spacing, speed / Faxen's in 0.05 s means): Shepard 1.12-1.14 from
t = 0.1 to 0.4 s while the mean wall pressure rose from 11 to 138 Pa (the reaction's pressure force
0.090 -> 0.189 N/m, the surface integral's 0.105-0.107); the fit 1.07-1.08 from t = 0.15 to 0.3 s;
the fit with the viscous part fitted too 0.988, 1.008, 1.013 at t = 0.15, 0.2, 0.25 s (the
reaction's viscous force was 0.0755-0.0785 N/m, the fitted one 0.090).
"""
import argparse, sys
from pathlib import Path
import numpy as np
ROOT = Path.cwd()
sys.path.insert(0, str(ROOT))
from launch.validate import faxen_terminal_speed
from sphcore.scene import load_scene
from sphcore.solver import Simulation

ap = argparse.ArgumentParser()
ap.add_argument("--scene", default=str(ROOT / "configs" / "settling_cylinder_closed_2d.toml"))
ap.add_argument("--set", dest="overrides", action="append", default=[])
ap.add_argument("--until", type=float, default=0.4)
ap.add_argument("--force", choices=("reaction", "surface"), default="surface")
ap.add_argument("--interp", choices=("shepard", "mls"), default="shepard")
ap.add_argument("--viscous", choices=("reaction", "surface"), default="reaction")
ap.add_argument("--order", type=int, default=1)
ap.add_argument("--points", type=int, default=256)
ap.add_argument("--report", type=float, default=0.05)
args = ap.parse_args()
scene = load_scene(args.scene, args.overrides)
ob = scene.obstacles[0]
a, dx = ob.radius, scene.particles.spacing
rho0 = scene.fluid.rest_density
faxen = faxen_terminal_speed(scene)
sim = Simulation(scene, "f64")
body = sim.model.walls.bodies[0]
H = scene.sph.support * dx
th = (np.arange(args.points) + 0.5) * 2 * np.pi / args.points
nq = np.stack([np.cos(th), np.sin(th)], 1)
dS = 2 * np.pi * a / args.points
log = {"ratio": []}

def wendland(r):
    q = np.clip(r / H, 0, 1)
    return (1 - q) ** 4 * (1 + 4 * q)

def surface_force():
    n = sim.state.n_owned
    x, m, rho, p = sim.state.x[:n, :2], sim.state.m[:n], sim.state.rho[:n], sim.state.p[:n]
    c = np.array(ob.center[:2]) + body.x[:2]
    near = np.hypot(x[:, 0] - c[0], x[:, 1] - c[1]) < a + H
    xs, V, ps, rs = x[near], m[near] / rho[near], p[near], rho[near]
    s = c + a * nq                                    # (Q, 2)
    r = np.hypot(s[:, None, 0] - xs[None, :, 0], s[:, None, 1] - xs[None, :, 1])
    W = wendland(r) * V[None, :]
    b = -body.a[:2]                                    # the fluid's body force in the wall's frame (gravity 0 here)
    ext = ps[None, :] + rs[None, :] * ((s[:, None, 0] - xs[None, :, 0]) * b[0] + (s[:, None, 1] - xs[None, :, 1]) * b[1])
    if args.interp == "shepard":
        pw = (W * ext).sum(1) / np.maximum(W.sum(1), 1e-300)
    else:  # weighted least squares p ~ alpha + beta . (x_j - s): p_w = alpha
        ux = xs[None, :, 0] - s[:, None, 0]
        uy = xs[None, :, 1] - s[:, None, 1]
        cols = [np.ones_like(ux), ux / H, uy / H] + ([ux * ux / H**2, ux * uy / H**2, uy * uy / H**2] if args.order == 2 else [])
        P = np.stack(cols, -1)
        A = np.einsum("qj,qjk,qjl->qkl", W, P, P)
        rhs = np.einsum("qj,qjk,qj->qk", W, P, ps[None, :] * np.ones_like(ux))
        pw = np.linalg.solve(A, rhs[..., None])[:, 0, 0]
    F = -(pw[:, None] * nq).sum(0) * dS
    if args.viscous == "surface":
        vs = sim.state.v[:n, :2][near] - body.v[None, :2]            # relative to the (translating) wall
        ux = xs[None, :, 0] - s[:, None, 0]
        uy = xs[None, :, 1] - s[:, None, 1]
        cols = [ux / H, uy / H] + ([ux * ux / H**2, ux * uy / H**2, uy * uy / H**2] if args.order == 2 else [])
        P = np.stack(cols, -1)
        A = np.einsum("qj,qjk,qjl->qkl", W, P, P)
        rhs = np.einsum("qj,qjk,jc->qkc", W, P, vs)
        X = np.linalg.solve(A, rhs)[:, :2, :] / H                   # X[q, k, c] = d u_c / d x_k at s_q
        mu = scene.sph.nu * rho0
        grad = np.transpose(X, (0, 2, 1))                           # grad[q, c, k] = d u_c / d x_k
        S = grad + np.transpose(grad, (0, 2, 1))
        tv = mu * np.einsum("qck,qk->qc", S, nq)
        Fv = tv.sum(0) * dS
        log.setdefault("visc", []).append(Fv[1])
        F = F + Fv
    return F, pw

orig = sim._body_forces
def patched(halo, prm):
    if args.force == "reaction":
        out = yield from orig(halo, prm)
        return out
    saved = sim.state.p.copy()
    sim.state.p[:] = 0.0
    out = yield from orig(halo, prm)
    sim.state.p[:] = saved
    full = yield from orig(halo, prm)
    if args.viscous == "surface":
        log.setdefault("rvisc", []).append(out[0][0][1])
        out = [(np.zeros(3), out[0][1])]
    F, pw = surface_force()
    f0, t0 = out[0]
    log["ratio"].append((full[0][0][1] - f0[1], F[1], pw.mean()))
    return [(f0 + np.array([F[0], F[1], 0.0]), t0)]
sim._body_forces = patched

report, speeds = args.report, []
while sim.t < args.until:
    sim.step()
    speeds.append(-body.v[1] / faxen)
    if sim.t < report:
        continue
    report += args.report
    n = sim.state.n_owned
    rho, p = sim.state.rho[:n], sim.state.p[:n]
    extra = ""
    if log["ratio"]:
        arr = np.array(log["ratio"]); log["ratio"] = []
        extra = f" | pressure force y: reaction {arr[:,0].mean():.3e}, surface {arr[:,1].mean():.3e} N/m; mean wall p {arr[:,2].mean():.1f}"
    if "visc" in log:
        extra += f" | viscous y: reaction {np.mean(log['rvisc']):.3e}, surface {np.mean(log['visc']):.3e}"
        log["visc"], log["rvisc"] = [], []
    print(f"t = {sim.t:.2f} s: speed {np.mean(speeds):.3f} U; mean rho {rho.mean():.2f}, p {p.min():.0f}..{p.max():.0f} Pa{extra}", flush=True)
    speeds = []
