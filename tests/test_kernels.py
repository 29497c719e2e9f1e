"""SPH kernels: normalisation, lattice sums and the gradient moments that SPH relies on."""

import numpy as np
import pytest

from taichi_mex import backend
from taichi_mex.core.kernels import Kernel


@pytest.fixture(scope="module")
def taichi_f64():
    backend.init("cpu", "f64")
    yield


def _lattice(factor, dx=1.0):
    m = int(np.ceil(factor)) + 1
    r = np.arange(-m, m + 1) * dx
    X, Y, Z = np.meshgrid(r, r, r, indexing="ij")
    return np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)


def _eval(kernel, xij):
    from taichi_mex.backend import ti

    xs = ti.Vector.field(3, float, shape=len(xij))
    w = ti.field(float, shape=len(xij))
    g = ti.Vector.field(3, float, shape=len(xij))
    xs.from_numpy(xij)

    @ti.kernel
    def run():
        for i in xs:
            w[i] = kernel.W(xs[i].norm())
            g[i] = kernel.grad(xs[i])

    run()
    return w.to_numpy(), g.to_numpy()


@pytest.mark.parametrize("kind, factor", [("cubic", 2.0), ("wendland_c2", 2.6)])
def test_kernel_integrates_to_one(kind, factor):
    k = Kernel(kind, factor)
    r = np.linspace(0, factor, 200001)
    integral = np.trapezoid(4 * np.pi * r**2 * k.W_np(r), r)
    assert integral == pytest.approx(1.0, abs=1e-6)
    assert k.W_np(factor) == 0.0 and k.W_np(1.01 * factor) == 0.0


@pytest.mark.parametrize("kind, factor", [("cubic", 2.0), ("wendland_c2", 2.6)])
def test_taichi_kernel_matches_numpy_and_derivative(taichi_f64, kind, factor):
    k = Kernel(kind, factor)
    r = np.linspace(0.0, 1.1 * factor, 301)
    x = np.stack([r, np.zeros_like(r), np.zeros_like(r)], axis=1)
    w, g = _eval(k, x)
    np.testing.assert_allclose(w, k.W_np(r), rtol=1e-12, atol=1e-15)
    fd = np.gradient(k.W_np(r), r)  # dW/dr by finite differences
    np.testing.assert_allclose(g[1:-1, 0], fd[1:-1], atol=2e-3 * np.abs(fd).max())
    np.testing.assert_allclose(k.F_np(r[1:]) * r[1:], g[1:, 0], rtol=1e-12, atol=1e-15)


# lattice quadrature of the kernel moments is off by ~2 % at these support radii
@pytest.mark.parametrize("kind, factor, tol", [("cubic", 2.0, 0.03), ("wendland_c2", 2.6, 0.03)])
def test_lattice_moments(taichi_f64, kind, factor, tol):
    """On a unit lattice: sum W ~ 1, sum grad W = 0, sum (x_j - x_i) (x) grad W_ij = I."""
    k = Kernel(kind, factor)
    pts = _lattice(factor)
    xij = -pts  # x_i = 0, x_ij = x_i - x_j
    w, g = _eval(k, xij)
    assert w.sum() == pytest.approx(1.0, abs=tol)
    np.testing.assert_allclose(g.sum(axis=0), 0.0, atol=1e-12)
    moment = np.einsum("ka,kb->ab", pts, g)  # (x_j - x_i) (x) grad_i W_ij
    np.testing.assert_allclose(moment, np.eye(3), atol=tol)


@pytest.mark.parametrize("kind", ["cubic", "wendland_c2"])
def test_a_kernel_keeps_its_arguments_precision(kind):
    """The coupled solve evaluates kernels in f64 inside an f32 run: W and F must not round
    through the default precision (Taichi warned 'Assign may lose precision' on every such
    compile, and the gradients carried 1e-7 relative errors into the f64 solve)."""
    from taichi_mex.backend import ti

    backend.init("cpu", "f32")
    try:
        k = Kernel(kind, 2.0)
        r = np.array([0.1234567890123, 0.61, 0.987654321, 1.4321, 1.97])
        rs = ti.field(ti.f64, shape=len(r))
        w = ti.field(ti.f64, shape=len(r))
        f = ti.field(ti.f64, shape=len(r))
        rs.from_numpy(r)

        @ti.kernel
        def run():
            for i in rs:
                w[i] = k.W(rs[i])
                f[i] = k.F(rs[i])

        run()
        # the kernel's constants are the run's (f32) numbers, a common factor; what must
        # not happen is each value rounded to f32 on its way out
        for values in (w.to_numpy(), f.to_numpy()):
            assert np.all(values.astype(np.float32).astype(np.float64) != values)
        assert np.allclose(w.to_numpy(), k.W_np(r), rtol=1e-6, atol=0)
        h = 1e-6  # F = (dW/dr) / r, by central differences
        dw = (k.W_np(r + h) - k.W_np(r - h)) / (2 * h) / r
        assert np.allclose(f.to_numpy(), dw, rtol=1e-6, atol=0)
    finally:
        backend.init("cpu", "f64")
