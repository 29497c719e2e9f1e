"""One matrix-free preconditioned conjugate-gradient solver for every implicit solve.

The method is Hestenes & Stiefel's conjugate gradients (J. Res. Natl. Bur. Stand. 49(6),
1952) with a preconditioner M, as in Saad, *Iterative Methods for Sparse Linear Systems*
(2nd ed., SIAM 2003), Algorithm 9.1:

    r0 = b - A x0,  z0 = M^-1 r0,  p0 = z0
    for j = 0, 1, ...:
        alpha = (r.z) / (p.Ap)
        x += alpha p,  r -= alpha Ap,  z = M^-1 r
        stop?
        beta = (r.z)_new / (r.z),  p = z + beta p

It is matrix-free: A is never assembled. The caller applies it (an SPH operator summed over
each particle's neighbours, whose pattern changes every step and whose entries cost as much to
store as to recompute), so one iteration costs one operator application, three dot products
(p.Ap, r.z and the stopping measure; the last two summed from one pass over the rows) and
a few per-row updates. The unknowns live on the
caller's rows (``rows.index[0..n)``, a ``FluidIndex``, in storage order, with
``rows.block_start`` saying where each ``BLOCK`` of particle indices begins in the list): a
scalar or a 3-vector per particle.

The caller is a ``@ti.data_oriented`` object passed as ``problem``; it provides these
``@ti.func`` methods (``mode`` is a compile-time value passed through unchanged, for a caller
with several systems, e.g. DFSPH's density and divergence solves):

* ``apply(n, skip, mode)``: ``Ap = A p`` on the rows (call-site: a kernel's top level, so it
  may run its own parallel loops); do nothing when ``skip != 0``;
* ``precondition(i, r, mode) -> z``: ``M^-1 r`` for row i (M must be SPD and block-diagonal);
* ``advance(i, alpha, mode)``: ``x_i += alpha p_i``, and whatever the caller keeps that
  follows x linearly (DFSPH moves the velocity with its pressure);
* ``residual_term(i, r, mode) -> float``: row i's share of the stopping measure (|r_i|,
  |r_i|^2, ...).

A solve is the caller's start kernel, which calls ``reset``, sets up its system and its warm
start x0, leaves r0 = b - A x0 in ``r`` and calls ``begin`` (or sets p = x0, applies A and
calls ``begin_from(b)``), and returns ``report()``; then ``iterate`` launches the iterations
until the stop (the begin shares the caller's launch: Taichi's per-launch and per-loop costs
are most of an iteration's on a small melt). The stopping rule is the caller's, given as
parameters (``Stop``); it is met when all of these hold:

    iterations >= min_iter
    error     = scale sum_i residual_term_i / ref <= tol       (ref: set by the caller)
    error_max = scale max_i residual_term_i       <= tol_max   (with track_max only)
    r.z <= rel2 (r0.z0)                                        (the preconditioned residual)

and the solve also stops after max_iter iterations. The test is made at the start too, so a
warm start that already meets it costs no iteration.

The scalars (alpha, beta, r.z, ...) are named f64 fields, and the dot products are
``BlockSum``s, accumulated in f64 in a fixed order: the iteration counts do not depend on
thread timing. ``chunk`` iterations are unrolled into one kernel launch (Taichi's launch costs
about as much as an iteration on a small melt); iterations after convergence do no work.
"""

from typing import NamedTuple

from taichi_mex.backend import ti
from taichi_mex.core.reduce import BLOCK, BlockSum


class Stop(NamedTuple):
    """The stopping rule (see the module docstring)."""

    tol: float = 0.0
    tol_max: float = float("inf")
    rel2: float = 1e300  # squared reduction of r.z wanted relative to r0.z0 (1e300: off)
    scale: float = 1.0
    min_iter: int = 0
    max_iter: int = 100


class Scalars:
    """The solver's named scalars, one 0-d field each (f64: they come from f64 sums)."""

    def __init__(self):
        f64 = dict(dtype=ti.f64, shape=())
        self.rz = ti.field(**f64)  # r.z of the current residual
        self.rz0 = ti.field(**f64)  # r0.z0, for the relative stop
        self.alpha = ti.field(**f64)
        self.beta = ti.field(**f64)
        self.ref = ti.field(**f64)  # what error's sum is divided by (the caller's: a count, |b|^2)
        self.res_sum = ti.field(**f64)  # sum of residual_term
        self.res_max = ti.field(**f64)  # largest residual_term (track_max)
        self.error = ti.field(**f64)
        self.error_max = ti.field(**f64)
        self.iterations = ti.field(dtype=ti.i32, shape=())
        self.done = ti.field(dtype=ti.i32, shape=())
        self.converged = ti.field(dtype=ti.i32, shape=())  # done by the rule, not by the cap


@ti.data_oriented
class PCG:
    def __init__(self, problem, rows, capacity: int, dim: int = 1, chunk: int = 4,
                 track_max: bool = False):
        """dim 1: one scalar unknown per row; else a dim-vector. track_max: also take the
        largest residual_term (error_max, for Stop.tol_max)."""
        self.problem = problem
        self.rows = rows
        self.dim = int(dim)
        self.chunk = int(chunk)
        self.track_max = bool(track_max)

        def vec():
            if self.dim == 1:
                return ti.field(float, shape=capacity)
            return ti.Vector.field(self.dim, float, shape=capacity)

        self.r, self.z, self.p, self.Ap = vec(), vec(), vec(), vec()
        # per-row terms of the sums (0 off the rows): two, so that one pass over the rows
        # writes both the stopping measure's and r.z's
        self.term = ti.field(float, shape=capacity)
        self.term_rz = ti.field(float, shape=capacity)
        self.sum = BlockSum(capacity)
        # per-block partial sums of an iteration's three reductions (f64), grouped as
        # ``sum`` groups them: one pass over the rows fills all three
        n_blocks = capacity // BLOCK + 2
        self.part_a = ti.field(ti.f64, shape=n_blocks)
        self.part_b = ti.field(ti.f64, shape=n_blocks)
        self.part_max = ti.field(ti.f64, shape=n_blocks)
        self.s = Scalars()

    # ---------------------------------------------------------------- for the caller's kernels
    @ti.func
    def reset(self):
        """Clear the scalars (ref = 1) and the sum terms of every live particle; call at the
        top level of the caller's start kernel, before it computes r0 or uses ``term``."""
        for i in range(self.rows.total[None]):
            self.term[i] = 0.0  # off the rows they stay 0 for this solve's sums
            self.term_rz[i] = 0.0
        ti.loop_config(serialize=True)
        for _ in range(1):
            self.s.rz[None] = 0.0
            self.s.rz0[None] = 0.0
            self.s.alpha[None] = 0.0
            self.s.beta[None] = 0.0
            self.s.res_sum[None] = 0.0
            self.s.res_max[None] = 0.0
            self.s.error[None] = 0.0
            self.s.error_max[None] = 0.0
            self.s.ref[None] = 1.0
            self.s.iterations[None] = 0
            self.s.done[None] = 0
            self.s.converged[None] = 0

    @ti.func
    def dot(self, a, b):
        out = ti.cast(0.0, float)
        if ti.static(self.dim == 1):
            out = a * b
        else:
            out = a.dot(b)
        return out

    @ti.func
    def record(self, tol, tol_max, scale, min_iter, max_iter):
        """For a relaxation method (DFSPH's Jacobi sweeps) sharing the scalars and the stopping
        rule: count an iteration whose residual terms are in ``term``, measure, and test."""
        self._measure()
        ti.loop_config(serialize=True)
        for _ in range(1):
            if self.s.done[None] == 0:
                self.s.iterations[None] += 1
                if self._met(tol, tol_max, 1.0, scale, min_iter, max_iter, 0.0):
                    self.s.done[None] = 1

    @ti.func
    def report(self):
        return ti.Vector([self.s.error[None], self.s.error_max[None],
                          ti.cast(self.s.iterations[None], ti.f64),
                          ti.cast(self.s.done[None], ti.f64)])

    # ---------------------------------------------------------------- pieces
    @ti.func
    def _measure(self):
        """res_sum (and res_max) of ``term`` over the rows; unchanged once done."""
        self.sum.sum(self.term, self.rows.total[None])
        ti.loop_config(serialize=True)
        for _ in range(1):
            if self.s.done[None] == 0:
                self.s.res_sum[None] = self.sum.total[None]
        if ti.static(self.track_max):
            self.sum.max(self.term, self.rows.total[None])
            ti.loop_config(serialize=True)
            for _ in range(1):
                if self.s.done[None] == 0:
                    self.s.res_max[None] = self.sum.total[None]

    @ti.func
    def _met(self, tol, tol_max, rel2, scale, min_iter, max_iter, rz):
        """Set error and error_max; True when the stopping rule holds or the cap is reached."""
        error = ti.cast(0.0, ti.f64)  # a zero residual has converged whatever ref is (no rows)
        if self.s.res_sum[None] > 0.0:
            error = self.s.res_sum[None] * scale / self.s.ref[None]
        error_max = self.s.res_max[None] * scale
        self.s.error[None] = error
        self.s.error_max[None] = error_max
        it = self.s.iterations[None]
        ok = error <= tol and rz <= rel2 * self.s.rz0[None] and it >= min_iter
        if ti.static(self.track_max):
            ok = ok and error_max <= tol_max
        self.s.converged[None] = 1 if ok else 0
        return ok or it >= max_iter

    @ti.func
    def begin(self, n, mode: ti.template(), tol, tol_max, rel2, scale, min_iter, max_iter):
        """From the r0 the caller left in ``r``: z0 = M^-1 r0, p0 = z0, r0.z0, the measure and
        the stopping test. Call at the top level of the caller's start kernel (after
        ``reset``), which then returns ``report()`` for ``iterate``; the stop's values come in
        as that kernel's arguments (``*stop``)."""
        self._begin_rows(n, self.r, False, mode, tol, tol_max, rel2, scale, min_iter, max_iter)

    @ti.func
    def begin_from(self, n, b: ti.template(), mode: ti.template(), tol, tol_max, rel2, scale,
                   min_iter, max_iter):
        """As ``begin``, with r0 = b - A x0: the caller has set p = x0 and called its
        ``apply(n, 0, mode)``, so that Ap = A x0 (its warm start)."""
        self._begin_rows(n, b, True, mode, tol, tol_max, rel2, scale, min_iter, max_iter)

    @ti.func
    def _begin_rows(self, n, b: ti.template(), from_b: ti.template(), mode: ti.template(), tol,
                    tol_max, rel2, scale, min_iter, max_iter):
        for blk in range(self._blocks()):
            sums = ti.Vector.zero(ti.f64, 3)
            for slot in range(self.rows.block_start[blk], self.rows.block_start[blk + 1]):
                i = self.rows.index[slot]
                r = self.r[i]
                if ti.static(from_b):
                    r = b[i] - self.Ap[i]
                    self.r[i] = r
                self.p[i] = self._measure_row(i, r, mode, sums)
            self._store_parts(blk, sums)
        ti.loop_config(serialize=True)
        for _ in range(1):
            rz = self._total(self.part_a)
            self.s.rz[None] = rz
            self.s.rz0[None] = rz
            self.s.res_sum[None] = self._total(self.part_b)
            if ti.static(self.track_max):
                self.s.res_max[None] = self._largest(self.part_max)
            if self._met(tol, tol_max, rel2, scale, min_iter, max_iter, rz):
                self.s.done[None] = 1

    @ti.func
    def _measure_row(self, i, r, mode: ti.template(), sums: ti.template()):
        """z = M^-1 r of row i (returned), its r.z and stopping term, kept per particle and
        added to the block's sums (r.z, the terms, the largest term)."""
        z = self.problem.precondition(i, r, mode)
        self.z[i] = z
        rz = self.dot(r, z)
        t = self.problem.residual_term(i, r, mode)
        self.term_rz[i] = rz
        self.term[i] = t
        sums[0] += ti.cast(rz, ti.f64)
        sums[1] += ti.cast(t, ti.f64)
        sums[2] = ti.max(sums[2], ti.cast(t, ti.f64))
        return z

    @ti.func
    def _store_parts(self, blk, sums):
        self.part_a[blk] = sums[0]
        self.part_b[blk] = sums[1]
        self.part_max[blk] = sums[2]

    @ti.func
    def _blocks(self):
        return (self.rows.total[None] + BLOCK - 1) // BLOCK

    @ti.func
    def _total(self, part: ti.template()):
        """The blocks' partial sums in order (inside a serial section)."""
        s = ti.cast(0.0, ti.f64)
        for blk in range(self._blocks()):
            s += part[blk]
        return s

    @ti.func
    def _largest(self, part: ti.template()):
        s = ti.cast(0.0, ti.f64)
        for blk in range(self._blocks()):
            s = ti.max(s, part[blk])
        return s

    # ---------------------------------------------------------------- kernels
    @ti.kernel
    def _iterate(self, n: ti.i32, tol: ti.f64, tol_max: ti.f64, rel2: ti.f64, scale: ti.f64,
                 min_iter: ti.i32, max_iter: ti.i32,
                 mode: ti.template()) -> ti.types.vector(4, ti.f64):
        """``chunk`` iterations of Saad's Alg. 9.1. Each iteration is the operator, then one
        pass over the rows per reduction point (p.Ap; the update with r.z and the stopping
        measure), each summing its rows block by block, and the serial scalar updates:
        Taichi's cost per parallel loop, not the arithmetic, is most of an iteration on a
        small melt, so the loops are as few as the algorithm's dependencies allow. The
        blocks group the sums as ``BlockSum`` over all live particles would: the same bits."""
        for _step in ti.static(range(self.chunk)):
            self.problem.apply(n, self.s.done[None], mode)
            for blk in range(self._blocks()):
                s_pap = ti.cast(0.0, ti.f64)
                if self.s.done[None] == 0:
                    for slot in range(self.rows.block_start[blk], self.rows.block_start[blk + 1]):
                        i = self.rows.index[slot]
                        pap = self.dot(self.p[i], self.Ap[i])
                        self.term[i] = pap
                        s_pap += ti.cast(pap, ti.f64)
                self.part_a[blk] = s_pap
            ti.loop_config(serialize=True)
            for _ in range(1):
                if self.s.done[None] == 0:
                    pAp = self._total(self.part_a)
                    self.s.alpha[None] = self.s.rz[None] / pAp if pAp > 0.0 else 0.0
                    self.s.iterations[None] += 1
            for blk in range(self._blocks()):
                sums = ti.Vector.zero(ti.f64, 3)
                if self.s.done[None] == 0:
                    a = ti.cast(self.s.alpha[None], float)
                    for slot in range(self.rows.block_start[blk], self.rows.block_start[blk + 1]):
                        i = self.rows.index[slot]
                        self.problem.advance(i, a, mode)
                        r = self.r[i] - a * self.Ap[i]
                        self.r[i] = r
                        self._measure_row(i, r, mode, sums)
                self._store_parts(blk, sums)
            ti.loop_config(serialize=True)
            for _ in range(1):
                if self.s.done[None] == 0:
                    self.s.res_sum[None] = self._total(self.part_b)
                    if ti.static(self.track_max):
                        self.s.res_max[None] = self._largest(self.part_max)
                    rz = self._total(self.part_a)
                    if self._met(tol, tol_max, rel2, scale, min_iter, max_iter, rz):
                        self.s.done[None] = 1
                    else:
                        rz_old = self.s.rz[None]
                        self.s.beta[None] = rz / rz_old if rz_old > 0.0 else 0.0
                        self.s.rz[None] = rz
            for slot in range(n):
                i = self.rows.index[slot]
                if self.s.done[None] == 0:
                    self.p[i] = self.z[i] + ti.cast(self.s.beta[None], float) * self.p[i]
        return self.report()

    # ---------------------------------------------------------------- driver
    def converged(self) -> bool:
        """Whether the last solve stopped by its rule (False: by the iteration cap)."""
        return bool(self.s.converged[None])

    def iterate(self, n: int, stop: Stop, mode, start) -> tuple[int, float, float]:
        """Iterate from ``start`` (the report of the kernel that called ``begin``) until the
        stop; returns (iterations, error, error_max). A launch runs ``chunk`` iterations, so
        none is launched when the start has converged."""
        out = start
        while out[3] == 0.0:
            out = self._iterate(n, *stop, mode)
        return int(out[2]), float(out[0]), float(out[1])
