"""Generate the small mesh files the scenes use (committed; rerun to recreate them).

    .venv/bin/python scripts/make_meshes.py      # writes configs/meshes/torus.stl

torus.stl: a ring (major radius 1, tube radius 0.35, unit-free: scenes scale it), ~1,900
triangles, binary STL.
"""
from pathlib import Path

import pyvista as pv

OUT = Path(__file__).resolve().parent.parent / "configs" / "meshes"


def main():
    OUT.mkdir(parents=True, exist_ok=True)
    torus = pv.ParametricTorus(ringradius=1.0, crosssectionradius=0.35, u_res=48, v_res=20, w_res=2)
    torus = torus.extract_surface().triangulate().clean()
    torus.save(OUT / "torus.stl", binary=True)
    print(f"wrote {OUT / 'torus.stl'}: {torus.n_cells} triangles, closed: {torus.n_open_edges == 0}")


if __name__ == "__main__":
    main()
