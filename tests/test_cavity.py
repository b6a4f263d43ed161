"""The lid-driven cavity case (`sph validate cavity`): its measurement tools and its quick run."""
import math

import numpy as np
import pytest

from launch.validate import (GHIA_U_RE100, GHIA_V_RE100, GHIA_X, GHIA_Y, largest_gap, mls_velocity,
                             run_validate)


def _lattice(n: int, dx: float):
    axis = (np.arange(n) + 0.5) * dx
    return np.stack(np.meshgrid(axis, axis, indexing="ij"), axis=-1).reshape(-1, 2)


@pytest.mark.fast
def test_ghia_tables_are_the_re_100_columns_with_the_walls_at_their_ends():
    for coordinate, values in ((GHIA_Y, GHIA_U_RE100), (GHIA_X, GHIA_V_RE100)):
        assert len(coordinate) == len(values) == 17
        assert np.all(np.diff(coordinate) < 0)           # printed from the lid (or the right wall) down
    assert (GHIA_U_RE100[0], GHIA_U_RE100[-1]) == (1.0, 0.0)   # the lid moves at U, the floor is at rest
    assert (GHIA_V_RE100[0], GHIA_V_RE100[-1]) == (0.0, 0.0)
    # the extremes of the Re = 100 columns (Table I: u_min at y = 0.4531; Table II: v at x = 0.2344, 0.8047)
    assert (GHIA_U_RE100.min(), GHIA_Y[GHIA_U_RE100.argmin()]) == (-0.21090, 0.4531)
    assert (GHIA_V_RE100.max(), GHIA_V_RE100.min()) == (0.17527, -0.24533)


@pytest.mark.fast
def test_the_linear_fit_is_exact_for_a_linear_field_against_a_wall_where_a_shepard_average_is_not():
    # Given particles on a lattice filling the unit square, carrying the linear field u = 1 + 2x - 3y
    dx, H = 0.05, 0.15
    x = _lattice(20, dx)
    v = np.column_stack([1.0 + 2.0 * x[:, 0] - 3.0 * x[:, 1], np.zeros(len(x))])
    points = np.array([[0.5, 0.5], [0.5, 0.99], [0.0, 0.3], [0.01, 0.01]])  # bulk, lid, wall, corner
    # When it is read at points in the bulk, by a wall and in a corner
    u = mls_velocity(x, v, points, H)[:, 0]
    # Then the fit returns the field there
    exact = 1.0 + 2.0 * points[:, 0] - 3.0 * points[:, 1]
    assert np.allclose(u, exact, rtol=0, atol=1e-12)
    # while a Shepard average by the lid reads the field at the centroid of the fluid in its
    # support, here 0.18 H below the point
    q = np.linalg.norm(x - points[1], axis=1) / H
    weight = np.where(q < 1, (1 - q) ** 4 * (1 + 4 * q), 0.0)
    centroid = weight @ x / weight.sum()
    assert math.isclose(weight @ v[:, 0] / weight.sum(), 1.0 + 2.0 * centroid[0] - 3.0 * centroid[1], abs_tol=1e-12)
    assert points[1, 1] - centroid[1] > 0.15 * H


@pytest.mark.fast
def test_the_largest_gap_is_half_a_diagonal_on_a_lattice_and_finds_a_hole():
    dx = 0.05
    x = _lattice(20, dx)
    gap, _ = largest_gap(x, (0.0, 0.0), (1.0, 1.0), dx)
    assert math.isclose(gap, dx / math.sqrt(2.0), rel_tol=1e-9)
    # a hole of 3 x 3 particles taken out of the middle
    hole = np.all(np.abs(x - 0.5) < 1.5 * dx, axis=1)
    gap, where = largest_gap(x[~hole], (0.0, 0.0), (1.0, 1.0), dx)
    assert gap > 1.5 * dx and np.allclose(where, 0.5, atol=0.5 * dx)
    # farther than H from the walls: a hole at a corner is not seen
    corner = np.all(x < 2.0 * dx, axis=1)
    gap, _ = largest_gap(x[~corner], (0.0, 0.0), (1.0, 1.0), dx, margin=0.15)
    assert math.isclose(gap, dx / math.sqrt(2.0), rel_tol=1e-9)


@pytest.mark.slow  # a validation case (a minute alone, two in a loaded CI): the slow tier, like `sph validate cavity --quick`; the metrics' pieces are tested above
def test_cavity_centreline_profiles_meet_their_tolerance(tmp_path, capsys):
    # the quick case: 40 particles across, the profiles averaged over t = 5-10 s against Ghia et al.
    run_validate(["cavity"], quick=True, out=tmp_path)
    lines = {x.split()[0]: x.split() for x in capsys.readouterr().out.splitlines() if x.startswith("cavity.")}
    assert lines["cavity.centreline_rms_of_U"][3] == "PASS", lines
    assert lines["cavity.centreline_max_of_U"][3] == "PASS", lines
    # the particles fill the cavity to its corners: shifting that counts the walls refills the lid's
    # upstream corner (without it, a void of 1.8 spacings there), and away from the walls they stay
    # packed (no tensile-instability void)
    gap = lines["cavity.largest_gap_of_dx"]
    assert gap[3] == "PASS" and float(gap[1]) < 1.5, gap
    bulk = float(" ".join(gap).rsplit("walls: ", 1)[1].rstrip(")"))
    assert bulk < 1.5, gap
    assert (tmp_path / "cavity.png").stat().st_size > 10_000
