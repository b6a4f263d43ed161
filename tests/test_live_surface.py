"""The live fluid surface (render.surface): peers' pieces of the colour field assemble into the
field of the whole domain, the viewer extracts a closed surface around the fluid, pieces off the
lattice are dropped, and "auto" turns it off for large runs."""
import types

import numpy as np
import pytest

from nodes.frames import SURFACE_SCALE, FrameMaker, domain_box, surface_lattice, surface_piece, surface_wanted
from nodes.recording import enclosed_volume
from sphcore.solver import Simulation

from conftest import scene


class Log:
    """A stand-in for the viewer's Rerun stream: keeps what was logged, by entity."""

    def __init__(self):
        self.logged = {}

    def log(self, entity, value, static=False):
        self.logged[entity] = value

    def set_time(self, *args, **kwargs):
        pass

    def send_blueprint(self, *args, **kwargs):
        pass

    def flush(self, timeout_sec=None):
        pass

    def disconnect(self):
        pass


def rows_near(sim, lo, hi):
    """A peer's view of ``sim``'s particles: the rows within H of the block [lo, hi) (its owned
    particles and ghosts), in their order."""
    s, H = sim.state, sim.H
    keep = np.all((s.x >= np.asarray(lo) - H) & (s.x < np.asarray(hi) + H), axis=1)
    state = types.SimpleNamespace(x=s.x[keep], m=s.m[keep], rho=s.rho[keep])
    return types.SimpleNamespace(state=state, prm=sim.prm, kernel=sim.kernel, H=sim.H, scene=sim.scene)


@pytest.fixture(scope="module")
def dam():
    sc = scene("dam_break", "particles.spacing=0.04")
    sim = Simulation(sc, "f64")
    for _ in range(30):
        sim.step()
    return sc, sim


def test_the_peers_pieces_assemble_into_the_field_of_the_whole_domain(dam):
    sc, sim = dam
    box = domain_box(sc)
    lattice = surface_lattice(sc, box, sim.n_particles)
    origin, step, shape = lattice
    # Given the field of one process over the whole domain
    at, whole = surface_piece(sim, lattice, None)
    # When four "peers" (blocks cut at x = 0.37 and z = 0.21, not on a node) each sample their own nodes
    lo, hi = np.array(box[0]) - 1.0, np.array(box[1]) + 1.0
    field = np.zeros(tuple(shape), dtype=np.uint8)
    taken = np.zeros(tuple(shape), dtype=np.int64)
    for x_lo, x_hi in ((lo[0], 0.37), (0.37, hi[0])):
        for z_lo, z_hi in ((lo[2], 0.21), (0.21, hi[2])):
            block = (np.array([x_lo, lo[1], z_lo]), np.array([x_hi, hi[1], z_hi]))
            piece = surface_piece(rows_near(sim, *block), lattice, block)
            assert piece is not None
            a, f = piece
            cut = tuple(slice(a[k], a[k] + f.shape[k]) for k in range(3))
            field[cut] = f
            taken[cut] += 1
    # Then together they are the whole field, bit for bit, and no node was sampled twice
    expected = np.zeros(tuple(shape), dtype=np.uint8)
    expected[tuple(slice(at[k], at[k] + whole.shape[k]) for k in range(3))] = whole
    assert np.array_equal(field, expected)
    assert taken.max() == 1
    assert whole.max() >= SURFACE_SCALE  # the inside of the fluid is there (c ~ 1)


def test_the_viewer_extracts_a_closed_surface_around_the_fluid(dam):
    from nodes.viewer import Viewer
    sc, sim = dam
    box = domain_box(sc)
    rec = Log()
    v = Viewer(sc, box, rec, world=1, particles=sim.n_particles)
    # When the viewer gets the whole field (a single process's piece)
    size = v._log_surface([surface_piece(sim, v.lattice, None)])
    v.close()
    # Then it logged a mesh whose vertices lie on the surface of the fluid, enclosing its volume
    mesh = rec.logged["fluid/surface"]
    import rerun as rr
    assert isinstance(mesh, rr.Mesh3D) and size > 0
    xyz = np.asarray(mesh.vertex_positions.as_arrow_array().to_pylist(), dtype=np.float64)
    tri = np.asarray(mesh.triangle_indices.as_arrow_array().to_pylist(), dtype=np.int64)
    normals = np.asarray(mesh.vertex_normals.as_arrow_array().to_pylist(), dtype=np.float64)
    fluid_volume = sim.n_particles * sc.particles.spacing ** 3
    volume = enclosed_volume(xyz, tri)
    assert volume == pytest.approx(fluid_volume, rel=0.05), (volume, fluid_volume)  # 2.3 % seen
    lo, hi = (np.asarray(b) for b in box)
    assert np.all(xyz >= lo - sc.particles.spacing) and np.all(xyz <= hi + sc.particles.spacing)
    # every vertex within a spacing of a particle, and the normals point out of the fluid
    x = sim.state.x[:sim.state.n_owned]
    near = np.sqrt(((xyz[:, None, :] - x[None, :, :]) ** 2).sum(axis=2)).min(axis=1)
    assert near.max() < 1.5 * sc.particles.spacing
    centre = x.mean(axis=0)
    assert (np.einsum("ij,ij->i", normals, xyz - centre) > 0).mean() > 0.9


def test_surface_pieces_off_the_lattice_are_dropped_and_counted():
    from nodes.viewer import Viewer, frame_arrays, frame_from_arrays
    from sphcore.render import Framelet
    sc = scene("tiny")
    rec = Log()
    v = Viewer(sc, domain_box(sc), rec, world=1, particles=10)
    shape = v.lattice[2]
    hostile = [(np.array([-1, 0, 0]), np.full((2, 2, 2), 200, np.uint8)),
               (np.array([2 ** 62, 0, 0]), np.full((2, 2, 2), 200, np.uint8)),
               (np.array([2 ** 63 - 1, 2 ** 63 - 1, 2 ** 63 - 1]), np.full((2, 2, 2), 200, np.uint8)),
               (shape - 1, np.full((2, 2, 2), 200, np.uint8))]
    assert v._log_surface(hostile) == 0
    v.close()
    assert v.bad_surfaces == 4 and type(rec.logged["fluid/surface"]).__name__ == "Clear"
    # and on the wire a surface must be uint8 in 3 dimensions with a (3,) int64 offset
    f = Framelet(0, 0, 0, np.zeros((1, 1, 3), np.uint8), np.ones((1, 1), np.float32), np.zeros((1, 1), np.int64))
    good = frame_arrays(f, {}, None, (np.array([1, 2, 3]), np.ones((2, 2, 2), np.uint8)))
    assert frame_from_arrays(0, good)[3][0].tolist() == [1, 2, 3]
    for bad in (dict(good, surface=np.ones((2, 2), np.uint8)), dict(good, surface=np.ones((2, 2, 2), np.float32)),
                dict(good, surface_at=np.array([1, 2])), {k: a for k, a in good.items() if k != "surface_at"}):
        with pytest.raises(ValueError, match="surface"):
            frame_from_arrays(0, bad)


def test_auto_turns_the_live_surface_off_for_large_runs_and_every_peer_samples_the_same_frames():
    from sphcore.scene import SURFACE_AUTO_MAX
    sc = scene("tiny")
    assert surface_wanted(sc, SURFACE_AUTO_MAX) and not surface_wanted(sc, SURFACE_AUTO_MAX + 1)
    assert surface_wanted(scene("tiny", "render.surface=on"), 10 ** 9)
    assert not surface_wanted(scene("tiny", "render.surface=off"), 1)
    every = scene("tiny", "render.every=10", "render.surface_every=3")
    maker = FrameMaker(every, domain_box(every), 0, 2, 100)
    due = [step for step in range(0, 100, 10) if maker.surface_due(types.SimpleNamespace(step_index=step))]
    assert due == [10, 40, 70]  # the first frame after step 0, then every third
    assert FrameMaker(every, domain_box(every), 0, 2, SURFACE_AUTO_MAX + 1).lattice is None
    # the step: one spacing, coarser above SURFACE_NODES particles (the fluid keeps about as many nodes)
    from sphcore.scene import SURFACE_NODES
    box, dx = domain_box(every), every.particles.spacing
    assert surface_lattice(every, box, SURFACE_NODES)[1] == pytest.approx(dx)
    assert surface_lattice(every, box, 8 * SURFACE_NODES)[1] == pytest.approx(2 * dx)
    assert surface_lattice(scene("tiny", "render.surface_step=0.5"), box, 10 ** 9)[1] == pytest.approx(dx / 2)
    assert surface_lattice(every, box, "many")[1] == pytest.approx(dx)  # a hostile count off the wire
