"""Smoothing kernels: normalisation and moments on a lattice, compact support, derivatives."""
import math

import numpy as np
import pytest

from sphcore.choices import Kernel
from sphcore.physics.kernels import dw_dr, dw_dr_over_r, kernel_constants, lap_w_viscosity, w

pytestmark = pytest.mark.fast  # make check runs this whole module

KERNELS = [Kernel.MULLER, Kernel.CUBIC_SPLINE, Kernel.WENDLAND_C2]


def lattice(dim, dx, H, offset):
    """Lattice points x_j - x_i around an evaluation point shifted by ``offset`` from a node."""
    k = int(math.ceil(H / dx)) + 2
    r = np.arange(-k, k + 1) * dx
    grids = np.meshgrid(*([r] * dim), indexing="ij")
    pts = np.stack([g.ravel() for g in grids], axis=1) - np.asarray(offset[:dim])
    return pts


def kernel_sums(kernel, dim, H, dx, offset):
    s_w, s_g, _ = kernel_constants(kernel, dim, H)
    x = lattice(dim, dx, H, offset)  # x_j - x_i
    r = np.linalg.norm(x, axis=1)
    V = dx**dim
    W = np.array([w(int(kernel), ri, H, s_w) for ri in r])
    dWr = np.array([dw_dr(int(kernel), ri, H, s_g) for ri in r])
    with np.errstate(invalid="ignore", divide="ignore"):
        unit = np.where(r[:, None] > 0, x / r[:, None], 0.0)
    # grad_i W(x_i - x_j) = dW/dr * (x_i - x_j)/r = -dW/dr * unit
    grad_i = -dWr[:, None] * unit
    return V, x, W, grad_i


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("kernel", KERNELS)
def test_partition_of_unity_and_gradient_moments(kernel, dim):
    # Given a lattice much finer than the support, evaluated off the nodes
    # (the spiky gradient jumps at r = 0, so its off-node sums need a finer lattice to converge)
    H, dx = 1.0, (1.0 / 40.0 if kernel == Kernel.MULLER else 1.0 / 8.0)
    offset = (0.31 * dx, 0.17 * dx, 0.07 * dx)
    V, x, W, grad_i = kernel_sums(kernel, dim, H, dx, offset)
    # Then sum W V = 1, sum grad W V = 0, sum (x_j - x_i) (x) grad_i W V = identity
    assert abs(np.sum(W) * V - 1.0) < 2e-3
    assert np.all(np.abs(grad_i.sum(axis=0) * V) < 3e-3 / H)
    moment = (x[:, :, None] * grad_i[:, None, :]).sum(axis=0) * V
    assert np.allclose(moment, np.eye(dim), atol=5e-3)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("kernel", KERNELS)
def test_moment_x_dw_dx_is_minus_one(kernel, dim):
    H, dx = 1.0, 1.0 / 8.0
    V, x, W, grad_i = kernel_sums(kernel, dim, H, dx, (0.0, 0.0, 0.0))
    # d W(x)/dx at x = x_j - x_i is -grad_i W
    assert abs(np.sum(x[:, 0] * (-grad_i[:, 0])) * V + 1.0) < 5e-3


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("kernel", KERNELS)
def test_compact_support_and_finite_difference_derivative(kernel, dim):
    H = 0.7
    s_w, s_g, s_l = kernel_constants(kernel, dim, H)
    for r in (H, 1.0001 * H, 2 * H):
        assert w(int(kernel), r, H, s_w) == 0.0
        assert dw_dr(int(kernel), r, H, s_g) == 0.0
        assert lap_w_viscosity(r, H, s_l) == 0.0
    if kernel == Kernel.MULLER:
        return  # density (poly6) and gradient (spiky) are different kernels by design
    eps = 1e-6
    for r in np.linspace(0.05, 0.95, 19) * H:
        fd = (w(int(kernel), r + eps, H, s_w) - w(int(kernel), r - eps, H, s_w)) / (2 * eps)
        assert dw_dr(int(kernel), r, H, s_g) == pytest.approx(fd, rel=1e-5, abs=1e-8 * s_w)
        assert dw_dr_over_r(int(kernel), r, H, s_g) == pytest.approx(fd / r, rel=1e-5, abs=1e-8 * s_w)


@pytest.mark.parametrize("dim", [2, 3])
def test_spiky_is_the_derivative_of_its_own_kernel(dim):
    H = 0.5
    _, s_g, _ = kernel_constants(Kernel.MULLER, dim, H)
    spiky = lambda r: s_g * (H - r) ** 3  # noqa: E731
    eps = 1e-7
    for r in np.linspace(0.05, 0.95, 10) * H:
        fd = (spiky(r + eps) - spiky(r - eps)) / (2 * eps)
        assert dw_dr(int(Kernel.MULLER), r, H, s_g) == pytest.approx(fd, rel=1e-5)
        assert dw_dr_over_r(int(Kernel.MULLER), r, H, s_g) == pytest.approx(fd / r, rel=1e-5)


@pytest.mark.parametrize("dim", [2, 3])
def test_spiky_and_viscosity_laplacian_normalisation(dim):
    # Given a fine lattice around the origin
    H, dx = 1.0, 1.0 / 10.0
    _, s_g, s_l = kernel_constants(Kernel.MULLER, dim, H)
    x = lattice(dim, dx, H, (0.0, 0.0, 0.0))
    r = np.linalg.norm(x, axis=1)
    V = dx**dim
    spiky = np.where(r < H, s_g * np.clip(H - r, 0, None) ** 3, 0.0)
    lap = np.array([lap_w_viscosity(ri, H, s_l) for ri in r])
    # Then the spiky kernel integrates to one and the Laplacian has the second moment 2
    assert abs(spiky.sum() * V - 1.0) < 5e-3
    assert abs(np.sum(lap * x[:, 0] ** 2) * V - 2.0) < 2e-2
