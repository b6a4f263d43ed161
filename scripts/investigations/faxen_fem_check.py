"""An independent check of the reference of `sph validate settling_cylinder`: the Stokes drag on a
cylinder moving along and midway between two plane walls, by Taylor-Hood (P2-P1) finite elements,
against Faxen's series (launch/validate.py faxen_drag).

    python3 -m venv /tmp/fem && /tmp/fem/bin/pip install scikit-fem gmsh meshio scipy
    /tmp/fem/bin/python scripts/investigations/faxen_fem_check.py --k 0.25 --size 0.05 --ends 10

(not the project's virtual environment: these packages are needed only here). In units of the
half-width l, viscosity mu = 1 and speed U = 1, the cylinder of radius a = k l moves along x at
U; every other boundary (the walls at y = +-l and the ends at x = +-ends l, a closed box) is at rest.
The drag per unit length, F / (mu U), is the sum of the reactions at the cylinder's x-velocity
degrees of freedom. The mesh is ``size`` x a at the cylinder, 0.15 l far from it. Measured
2026-12-05: k = 0.25: 21.9386 (size 0.1) and 21.9571 (0.05) against the series' 21.9643; k = 0.4:
52.2905 (0.1) against 52.5688; a closed box 6 l long (ends 3) gives the same 21.9386 as 20 l.

    .venv/bin/python scripts/investigations/settling_cylinder_drag.py --profile /tmp/profile.npz
    /tmp/fem/bin/python scripts/investigations/faxen_fem_check.py --size 0.1 --compare /tmp/profile.npz

compares the flow around the settling cylinder with the finite elements' at the same speed.
"""
import argparse
import math
import tempfile
from pathlib import Path

import gmsh
import meshio
import numpy as np
from scipy.sparse import bmat
from skfem import (Basis, BilinearForm, ElementTriP1, ElementTriP2, ElementVectorH1, MeshTri, asm, condense,
                   solve)
from skfem.helpers import ddot, grad
from skfem.models.general import divergence



def faxen_drag(k: float) -> float:
    """Faxen's series, typed again from the literature (launch/validate.py has the case's copy; this
    environment has no numba to import it with)."""
    return 4.0 * math.pi / (-math.log(k) - 0.9157 + 1.7244 * k ** 2 - 1.7302 * k ** 4 + 2.4056 * k ** 6
                            - 4.5913 * k ** 8)


def mesh_of(k: float, size: float, ends: float, folder: Path) -> MeshTri:
    """Triangles of the box [-ends, ends] x [-1, 1] less the disc of radius k (gmsh)."""
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    occ = gmsh.model.occ
    box, disc = occ.addRectangle(-ends, -1.0, 0, 2.0 * ends, 2.0), occ.addDisk(0, 0, 0, k, k)
    occ.cut([(2, box)], [(2, disc)])
    occ.synchronize()
    circle = [c for _, c in gmsh.model.getEntities(1) if abs(occ.getMass(1, c) - 2.0 * math.pi * k) < 1e-9]
    field = gmsh.model.mesh.field
    distance = field.add("Distance")
    field.setNumbers(distance, "CurvesList", circle)
    field.setNumber(distance, "Sampling", 400)
    threshold = field.add("Threshold")
    field.setNumber(threshold, "InField", distance)
    field.setNumber(threshold, "SizeMin", size * k)
    field.setNumber(threshold, "SizeMax", 0.15)
    field.setNumber(threshold, "DistMin", 0.0)
    field.setNumber(threshold, "DistMax", 2.0)
    field.setAsBackgroundMesh(threshold)
    gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
    gmsh.model.mesh.generate(2)
    path = folder / "mesh.msh"
    gmsh.write(str(path))
    gmsh.finalize()
    m = meshio.read(path)
    return MeshTri(m.points[:, :2].T.copy(), m.cells_dict["triangle"].T.copy())


def drag(k: float, size: float, ends: float):
    """(F / (mu U), triangles, velocity basis, velocity) of the cylinder of radius k in the closed box
    (module docstring)."""
    with tempfile.TemporaryDirectory() as tmp:
        mesh = mesh_of(k, size, ends, Path(tmp))
    ub, pb = Basis(mesh, ElementVectorH1(ElementTriP2()), intorder=4), Basis(mesh, ElementTriP1(), intorder=4)
    viscous = BilinearForm(lambda u, v, w: ddot(grad(u), grad(v))).assemble(ub)
    div = -asm(divergence, ub, pb)
    mass = asm(BilinearForm(lambda p, q, w: p * q), pb)
    K = bmat([[viscous, -div.T], [-div, 1e-12 * mass]], "csr")  # a tiny pressure mass: the singular block
    dofs = ub.get_dofs()
    ux, uy = dofs.all("u^1"), dofs.all("u^2")
    x, y = ub.doflocs
    on_cylinder = np.hypot(x, y) < k + 1e-6
    moving = ux[on_cylinder[ux]]
    u = np.zeros(K.shape[0])
    u[moving] = 1.0
    u = solve(*condense(K, np.zeros(K.shape[0]), x=u, D=np.concatenate([ux, uy])))
    return float((K @ u)[moving].sum()), mesh.nelements, ub, u[: ub.N]


def compare(profile, size: float):
    """The SPH particles' velocity (the body moving down, -y) mapped to the finite elements' frame
    (the body moving along +x: x_fe = -y, y_fe = x, u_fe = -v_y), binned beside the body and along the
    axis, against the finite elements at the same points; both in units of the body's speed."""
    k = float(profile["k"])
    _, _, ub, u = drag(k, size, 3.0)  # the case's tank: the body 3 half-widths from floor and surface

    def fe(px, py):
        return float((ub.probes(np.array([[px], [py]])) @ u)[0])
    p = profile["points"]
    xf, yf, uf = -p[:, 1], p[:, 0], -p[:, 3]
    print("beside the body (x ~ 0): y / l, SPH, finite elements")
    beside = np.abs(xf) < 0.03
    for y in np.arange(k + 0.025, 1.0, 0.05):
        m = beside & (np.abs(np.abs(yf) - y) < 0.025)
        if m.any():
            print(f"  {y:.3f}  {uf[m].mean():+.3f}  {fe(0.0, y):+.3f}")
    print("along the axis (y ~ 0, + ahead): x / l, SPH, finite elements")
    axis = np.abs(yf) < 0.03
    for x in [-2.0, -1.5, -1.0, -0.5, 0.5, 1.0, 1.5, 2.0]:
        m = axis & (np.abs(xf - x) < 0.05)
        if m.any():
            print(f"  {x:+.2f}  {uf[m].mean():+.3f}  {fe(x, 0.0):+.3f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--k", type=float, default=0.25, help="radius / half-width (default 0.25)")
    ap.add_argument("--size", type=float, default=0.05, help="element size at the cylinder / radius (default 0.05)")
    ap.add_argument("--ends", type=float, default=10.0, help="the box's half-length / half-width (default 10)")
    ap.add_argument("--compare", type=Path, default=None,
                    help="an SPH run's profile (settling_cylinder_drag.py --profile): its velocity along the "
                         "axis and across the channel beside the body, against the finite elements' (k from it)")
    args = ap.parse_args()
    if args.compare:
        compare(np.load(args.compare), args.size)
        return
    value, triangles, _, _ = drag(args.k, args.size, args.ends)
    series = faxen_drag(args.k)
    print(f"k = {args.k}: finite elements F / (mu U) = {value:.4f} ({triangles} triangles), Faxen's series "
          f"{series:.4f}, ratio {value / series:.4f}")


if __name__ == "__main__":
    main()
