"""core/pcg.py: the one preconditioned CG, on a small SPD system held in Taichi fields.

The system is a 1D chain Laplacian with varying couplings and a positive diagonal shift
(scalar unknowns), or the same chain acting on 3-vectors with an SPD 3x3 block on each
diagonal (block-Jacobi preconditioner). Some particles are left off the rows: they act as
zero Dirichlet values, as walls do in the solvers."""

import numpy as np
import pytest

from taichi_mex import backend
from taichi_mex.backend import ti

N = 40
UNLISTED = (0, 7, 19, 33)  # particles off the rows (zero values)


def _chain(dim):
    from taichi_mex.core.pcg import PCG

    @ti.data_oriented
    class Rows:
        def __init__(self, listed):
            self.index = ti.field(ti.i32, shape=N)
            self.total = ti.field(ti.i32, shape=())
            self.index.from_numpy(np.array(list(listed) + [0] * (N - len(listed)), np.int32))
            self.total[None] = N
            self.n = len(listed)
            # where each BLOCK of particle indices starts in the list (FluidIndex's layout)
            from taichi_mex.core.reduce import BLOCK
            edges = np.arange(0, N // BLOCK + 2) * BLOCK
            starts = np.searchsorted(np.asarray(listed), edges).astype(np.int32)
            self.block_start = ti.field(ti.i32, shape=len(starts))
            self.block_start.from_numpy(starts)

    @ti.data_oriented
    class Chain:
        """A p = sum over links (i, i+1): c_i (p_i - p_{i+1}) on both ends, + S_i p_i."""

        def __init__(self, chunk=4):
            rng = np.random.default_rng(7)
            self.listed_np = np.ones(N, bool)
            self.listed_np[list(UNLISTED)] = False
            self.rows = Rows(np.flatnonzero(self.listed_np))
            self.dim = dim
            self.c_np = rng.uniform(0.5, 2.0, N)  # c[i] couples i and i+1 (c[N-1] unused)
            S = []
            for _ in range(N):
                if dim == 1:
                    S.append(rng.uniform(0.01, 0.1))
                else:
                    Q = rng.normal(size=(dim, dim))
                    S.append(0.05 * (Q @ Q.T) + 0.01 * np.eye(dim))
            self.S_np = np.array(S)
            self.b_np = rng.normal(size=(N, dim)) if dim > 1 else rng.normal(size=N)
            self.listed = ti.field(ti.i32, shape=N)
            self.listed.from_numpy(self.listed_np.astype(np.int32))
            self.c = ti.field(float, shape=N)
            self.c.from_numpy(self.c_np)
            if dim == 1:
                self.S = ti.field(float, shape=N)
                self.Minv = ti.field(float, shape=N)
                self.x = ti.field(float, shape=N)
                self.b = ti.field(float, shape=N)
            else:
                self.S = ti.Matrix.field(dim, dim, float, shape=N)
                self.Minv = ti.Matrix.field(dim, dim, float, shape=N)
                self.x = ti.Vector.field(dim, float, shape=N)
                self.b = ti.Vector.field(dim, float, shape=N)
            self.S.from_numpy(self.S_np)
            self.b.from_numpy(self.b_np)
            self.Minv.from_numpy(self._inverse_diagonal())
            self.cg = PCG(self, self.rows, N, dim=dim, chunk=chunk)

        def _inverse_diagonal(self):
            cl = np.concatenate([[0.0], self.c_np[:-1]])
            cr = np.concatenate([self.c_np[:-1], [0.0]])
            if self.dim == 1:
                return 1.0 / (cl + cr + self.S_np)
            return np.linalg.inv(self.S_np + (cl + cr)[:, None, None] * np.eye(self.dim))

        def dense(self):
            """A and b over the rows, in slot order (component fastest)."""
            rows = np.flatnonzero(self.listed_np)
            pos = {i: k for k, i in enumerate(rows)}
            d = self.dim
            A = np.zeros((len(rows) * d, len(rows) * d))
            I = np.eye(d)
            for k, i in enumerate(rows):
                S = self.S_np[i] * I if d == 1 else self.S_np[i]
                A[k * d:(k + 1) * d, k * d:(k + 1) * d] += S
                for j, c in ((i - 1, self.c_np[i - 1] if i > 0 else 0.0),
                             (i + 1, self.c_np[i] if i < N - 1 else 0.0)):
                    if 0 <= j < N:
                        A[k * d:(k + 1) * d, k * d:(k + 1) * d] += c * I
                        if j in pos:
                            m = pos[j]
                            A[k * d:(k + 1) * d, m * d:(m + 1) * d] -= c * I
            b = self.b_np[rows].reshape(-1)
            return A, b, rows

        # the PCG protocol
        @ti.func
        def apply(self, n, skip, mode: ti.template()):
            for slot in range(n):
                i = self.rows.index[slot]
                if skip == 0:
                    pi = self.cg.p[i]
                    out = self._mul(self.S[i], pi)
                    if i > 0:
                        out += self.c[i - 1] * (pi - self.listed[i - 1] * self.cg.p[i - 1])
                    if i < N - 1:
                        out += self.c[i] * (pi - self.listed[i + 1] * self.cg.p[i + 1])
                    self.cg.Ap[i] = out

        @ti.func
        def _mul(self, M, v):
            out = v
            if ti.static(self.dim == 1):
                out = M * v
            else:
                out = M @ v
            return out

        @ti.func
        def precondition(self, i, r, mode: ti.template()):
            return self._mul(self.Minv[i], r)

        @ti.func
        def advance(self, i, alpha, mode: ti.template()):
            self.x[i] += alpha * self.cg.p[i]

        @ti.func
        def residual_term(self, i, r, mode: ti.template()):
            return self.cg.dot(r, r)

        @ti.kernel
        def start(self, n: ti.i32, tol: ti.f64, tol_max: ti.f64, rel2: ti.f64, scale: ti.f64,
                  min_iter: ti.i32, max_iter: ti.i32) -> ti.types.vector(4, ti.f64):
            """Warm start from x: r0 = b - A x0; ref = |b|^2, so error = |r|^2 / |b|^2."""
            self.cg.reset()
            for slot in range(n):
                i = self.rows.index[slot]
                self.cg.term[i] = self.cg.dot(self.b[i], self.b[i])
                self.cg.p[i] = self.x[i]
            self.cg.sum.sum(self.cg.term, self.rows.total[None])
            ti.loop_config(serialize=True)
            for _ in range(1):
                self.cg.s.ref[None] = self.cg.sum.total[None]
            self.apply(n, 0, 0)
            self.cg.begin_from(n, self.b, 0, tol, tol_max, rel2, scale, min_iter, max_iter)
            return self.cg.report()

        def solve(self, stop):
            n = self.rows.n
            return self.cg.iterate(n, stop, 0, self.start(n, *stop))

        def solution(self):
            return self.x.to_numpy()[self.listed_np].reshape(-1)

    return Chain


@pytest.fixture(scope="module", autouse=True)
def _f64():
    backend.init("cpu", "f64")


@pytest.mark.parametrize("dim", [1, 3])
def test_pcg_matches_numpy_solve(dim):
    from taichi_mex.core.pcg import Stop

    chain = _chain(dim)()
    A, b, rows = chain.dense()
    assert np.allclose(A, A.T) and np.linalg.eigvalsh(A).min() > 0  # SPD
    exact = np.linalg.solve(A, b)
    iters, err, _ = chain.solve(Stop(tol=1e-26, max_iter=10 * len(b)))
    x = chain.solution()
    assert np.linalg.norm(x - exact) <= 1e-11 * np.linalg.norm(exact)
    assert err <= 1e-26
    assert 0 < iters <= len(b) + 5  # CG: at most as many iterations as unknowns, up to rounding
    off = chain.x.to_numpy()[~chain.listed_np]
    assert np.all(off == 0.0)  # rows off the list are never touched


def test_warm_start_at_the_solution_takes_no_iteration():
    from taichi_mex.core.pcg import Stop

    chain = _chain(1)()
    A, b, rows = chain.dense()
    guess = np.zeros(N)
    guess[rows] = np.linalg.solve(A, b)
    chain.x.from_numpy(guess)
    iters, err, _ = chain.solve(Stop(tol=1e-24, max_iter=100))
    assert iters == 0 and err <= 1e-24
    assert np.array_equal(chain.x.to_numpy(), guess)  # untouched
    # min_iter forces iterations even then; they only polish the rounding of the guess
    iters, err, _ = chain.solve(Stop(tol=1e-24, min_iter=2, max_iter=100))
    assert iters == 2 and np.allclose(chain.x.to_numpy(), guess, rtol=1e-13, atol=1e-15)


@pytest.mark.parametrize("cap", [0, 3, 6])
def test_iteration_cap_is_exact_whatever_the_chunk(cap):
    """The cap holds to the iteration although 4 iterations run per launch, and stopping in
    the middle of a launch leaves the same x as one iteration per launch."""
    from taichi_mex.core.pcg import Stop

    out = []
    for chunk in (4, 1):
        chain = _chain(3)(chunk=chunk)
        iters, err, _ = chain.solve(Stop(tol=1e-30, max_iter=cap))
        assert iters == cap and err > 1e-30
        out.append(chain.x.to_numpy())
    assert np.array_equal(out[0], out[1])


def test_relative_stop_on_the_preconditioned_residual():
    """rel2 alone (tol infinite) stops once r.z has fallen below rel2 r0.z0."""
    from taichi_mex.core.pcg import Stop

    chain = _chain(1)()
    iters, _, _ = chain.solve(Stop(tol=float("inf"), rel2=1e-6, max_iter=200))
    A, b, rows = chain.dense()
    x = chain.solution()
    Minv = np.diag(1.0 / np.diag(A))
    r = b - A @ x
    assert iters > 0 and r @ Minv @ r <= 1e-6 * (b @ Minv @ b)
    chain2 = _chain(1)()
    iters2, _, _ = chain2.solve(Stop(tol=float("inf"), rel2=1e-6, max_iter=iters - 1))
    x2 = chain2.solution()
    r2 = b - A @ x2
    assert r2 @ Minv @ r2 > 1e-6 * (b @ Minv @ b)  # one iteration fewer was not enough
