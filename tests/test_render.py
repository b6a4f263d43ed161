"""Splat renderer and sort-last compositing."""
import numpy as np
import pytest

from sphcore.render import (BACKGROUND, LUT, OUTLINE, Camera, colours, composite, draw_box, framelet,
                            framing_camera, render)


def lattice_and_blob(n_random=1500, seed=0):
    """A lattice (many exactly equal depths: ties) plus random particles."""
    g = np.arange(8) * 0.05
    lat = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    rnd = np.random.default_rng(seed).random((n_random, 3)) * 0.4
    x = np.concatenate([lat, rnd])
    ids = np.random.default_rng(seed + 1).permutation(len(x)).astype(np.int64)
    return x, ids


CAM = Camera(eye=(0.2, 0.2, 1.5), target=(0.2, 0.2, 0.2), width=160, height=120)  # straight on: many ties


@pytest.mark.parametrize("camera", [CAM, framing_camera((0, 0, 0), (0.4, 0.4, 0.4), 200, 150)])
def test_composite_of_framelets_equals_the_render_of_all_particles(camera):
    # Given particles split arbitrarily among 3 peers
    x, ids = lattice_and_blob()
    base = colours(x[:, 1], 0.0, 0.4)
    owner = np.random.default_rng(5).integers(0, 3, len(x))
    full = render(camera, x, base, ids, 0.03)
    # When each peer renders its own particles into a framelet and the framelets are composited
    frames = [framelet(r, *render(camera, x[owner == r], base[owner == r], ids[owner == r], 0.03)) for r in range(3)]
    rgb, depth, idbuf = composite(frames, camera.width, camera.height)
    # Then the composite is pixel-identical to rendering all particles at once (ties go to the lower id)
    assert np.array_equal(idbuf, full[2]) and np.array_equal(depth, full[1]) and np.array_equal(rgb, full[0])
    assert (full[2] >= 0).mean() > 0.2  # the test image is not empty
    # and the result does not depend on the order of particles or framelets
    perm = np.random.default_rng(9).permutation(len(x))
    again = render(camera, x[perm], base[perm], ids[perm], 0.03)
    assert all(np.array_equal(a, b) for a, b in zip(again, full))
    rev = composite(frames[::-1], camera.width, camera.height)
    assert all(np.array_equal(a, b) for a, b in zip(rev, (rgb, depth, idbuf)))


def test_nearest_particle_wins_and_empty_pixels_are_background():
    cam = Camera(eye=(0, 0, 2.0), target=(0, 0, 0), width=64, height=64)
    x = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.5]])  # the second is nearer the camera
    rgb, depth, idbuf = render(cam, x, np.array([[255, 0, 0], [0, 255, 0]], np.uint8), np.array([7, 3]), 0.1)
    assert idbuf[32, 32] == 3 and abs(depth[32, 32] - (1.5 - 0.1)) < 1e-3  # the front of the nearer sphere
    assert rgb[32, 32, 1] > 0 and rgb[32, 32, 0] == 0
    assert idbuf[0, 0] == -1 and np.isinf(depth[0, 0]) and np.array_equal(rgb[0, 0], BACKGROUND)
    f = framelet(0, rgb, depth, idbuf)
    assert 0 < f.w < 64 and 0 < f.h < 64 and (f.id >= 0).any()


def test_framing_camera_sees_the_whole_box_and_the_outline_is_drawn():
    lo, hi = (0.0, 0.0, 0.0), (1.6, 0.6, 0.6)
    cam = framing_camera(lo, hi, 320, 240)
    corners = np.array([[a, b, c] for a in (lo[0], hi[0]) for b in (lo[1], hi[1]) for c in (lo[2], hi[2])])
    _, _, idbuf = render(cam, corners, np.full((8, 3), 200, np.uint8), np.arange(8), 0.01)
    assert len(np.unique(idbuf[idbuf >= 0])) == 8  # every corner is on screen
    rgb = np.zeros((240, 320, 3), np.uint8)
    draw_box(cam, lo, hi, rgb, np.full((240, 320), np.inf, np.float32))
    assert (rgb == OUTLINE).all(-1).sum() > 500


def test_colours_clamp_to_the_range():
    c = colours(np.array([-1.0, 0.0, 0.5, 1.0, 2.0]), 0.0, 1.0)
    assert np.array_equal(c[0], LUT[0]) and np.array_equal(c[1], LUT[0])
    assert np.array_equal(c[3], LUT[-1]) and np.array_equal(c[4], LUT[-1])
