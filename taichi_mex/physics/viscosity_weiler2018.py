"""Implicit viscosity: Weiler, Koschier, Brand & Bender, "A physically consistent implicit
viscosity solver for SPH fluids", Computer Graphics Forum 37(2), 2018.

Backward Euler on the SPH viscosity operator (their Eq. 8, d = 10 in 3D):

    v_i - dt/rho_i sum_j d mu_ij (m_j/rho_j) (v_ij . x_ij)/(|x_ij|^2 + 0.01 H^2) grad W_ij
        - dt/rho_i sum_b d mu_b (rho0 V_b/rho_i) ((v_i - v_b) . x_ib)/(|x_ib|^2 + 0.01 H^2) grad W_ib
        = v*_i

with mu_ij the harmonic mean (keeps the matrix symmetric for temperature-dependent mu) and
mu_b = mu_i for no-slip walls (the plate, the nozzle, solidified melt, the inlet column).
The system is symmetric positive definite; it is solved matrix-free by the shared
preconditioned conjugate gradients (``core.pcg``) with a 3x3 block-Jacobi preconditioner,
warm-started with the previous step's velocity change, to a relative residual |r| <= tol |b|.

The constant d = 10 makes the operator exact in the continuum; on the particle lattice at
the low neighbour counts DFSPH runs with (cubic spline, H = 2 dx: ~33 neighbours) the sum
reproduces only 70 % of nu u'' for u = z^2/2 (Wendland at H = 2.6 dx: 84 %). Like the
rest volume, we calibrate d on the lattice so that a quadratic shear profile diffuses at
the set viscosity (see ``lattice_laplacian_factor``).
"""

import numpy as np

from taichi_mex.backend import ti
from taichi_mex.core.pcg import PCG, Stop
from taichi_mex.core.state import FLUID


def lattice_links(kernel, spacing_m: float):
    """A cubic lattice's links from the origin within the support: offsets P (n, 3), their
    lengths d and F = (dW/dr) / r, and u_i - u_j for u = z^2/2 (the calibration's field)."""
    m = int(np.ceil(kernel.H / spacing_m)) + 1
    r = np.arange(-m, m + 1) * spacing_m
    X, Y, Z = np.meshgrid(r, r, r, indexing="ij")
    P = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    d = np.linalg.norm(P, axis=1)
    ok = (d > 0) & (d < kernel.H)
    P, d = P[ok], d[ok]
    eps = 1e-6 * spacing_m
    F = (kernel.W_np(d + eps) - kernel.W_np(d - eps)) / (2 * eps) / d
    return P, d, F, -0.5 * P[:, 2] ** 2


def lattice_laplacian_factor(kernel, spacing_m: float, volume_m3: float) -> float:
    """What the d = 10 operator gives for u = z^2/2 (exact: 1) on the cubic lattice."""
    P, d, F, u_diff = lattice_links(kernel, spacing_m)
    return float(10.0 * np.sum(volume_m3 * u_diff * P[:, 0] ** 2 * F / (d**2 + 0.01 * kernel.H**2)))


@ti.data_oriented
class ImplicitViscosity:
    #: per-neighbour coefficients and block preconditioner, rebuilt by every solve's setup:
    #: not part of a checkpoint (sim/checkpoint.py)
    checkpoint_skip = ("cF", "Binv")

    def __init__(self, state, grid, kernel, viscosity, mass_kg: float, rho0: float,
                 spacing_m: float, tolerance: float, max_iterations: int, fluid,
                 no_slip: bool = True, chunk: int = 4):
        self.state = state
        self.chunk = int(chunk)  # CG iterations per kernel launch (DFSPHOptions.cg_chunk)
        self.fl = fluid  # state.FluidIndex: every loop here runs over fluid only
        self.grid = grid
        self.K = kernel
        self.visc = viscosity
        self.mass = float(mass_kg)
        self.rho0 = float(rho0)
        self.lattice_factor = lattice_laplacian_factor(kernel, spacing_m, mass_kg / rho0)
        self.d = 10.0 / self.lattice_factor
        self.eps = 0.01 * kernel.H * kernel.H
        self.tol = float(tolerance)
        self.max_iterations = int(max_iterations)
        self.no_slip = bool(no_slip)
        cap = state.capacity
        self.vdiff = state.add("viscosity_warm_start", 3)
        self.Vb = mass_kg / rho0  # wall particles stand for one lattice cell, like fluid
        self.x = ti.Vector.field(3, float, shape=cap)  # the new velocity
        self.rhs = ti.Vector.field(3, float, shape=cap)
        self.Binv = ti.Matrix.field(3, 3, float, shape=cap)
        # c F of every listed pair, computed once per step: the iterations only read it
        self.cF = ti.field(float, shape=(cap, grid.max_neighbours))
        self.dt = ti.field(float, shape=())  # this solve's step (the operator depends on it)
        # error = |r|^2 / |b|^2 (ref = |b|^2), CG iterations run on the fluid rows
        self.cg = PCG(self, fluid, cap, dim=3, chunk=self.chunk)
        self.r, self.z, self.p, self.Ap = self.cg.r, self.cg.z, self.cg.p, self.cg.Ap
        self.stats = {"viscosity_iterations": 0, "viscosity_residual": 0.0}

    # ---------------------------------------------------------------- operator
    @ti.func
    def _coef(self, i, j, r2):
        """dt-free coupling d mu (volume term) / (rho_i (r^2 + eps)) for pair (i, j)."""
        st = self.state
        mu_i = self.visc.eta_of(i)
        c = 0.0
        if st.phase[j] == FLUID:
            mu_j = self.visc.eta_of(j)
            mu = 2.0 * mu_i * mu_j / (mu_i + mu_j + 1e-30)
            c = self.d * mu * (st.m[j] / st.rho[j]) / st.rho[i] / (r2 + self.eps)
        elif ti.static(self.no_slip):
            c = self.d * mu_i * (self.rho0 * self.Vb / st.rho[i]) / st.rho[i] / (r2 + self.eps)
        return c

    @ti.func
    def _apply_task(self, i, slot, j, xij, acc: ti.template()):
        # acc[0:3]: sum over pairs of c F ((u_i - u_j) . x) x, with u_b = 0 (walls live in rhs)
        uj = ti.Vector([0.0, 0.0, 0.0])
        if self.state.phase[j] == FLUID:
            uj = self.p[j]
        acc += self.cF[i, slot] * (self.p[i] - uj).dot(xij) * xij

    @ti.func
    def _setup_task(self, i, slot, j, xij, acc: ti.template()):
        """Cache c F for the step's iterations; accumulate the wall term of the rhs (acc[0:3])
        and the 3x3 diagonal block (acc[3:12], row-major)."""
        r2 = xij.norm_sqr()
        cF = 0.0
        if r2 < self.K.H * self.K.H:
            cF = self._coef(i, j, r2) * self.K.F(ti.sqrt(r2))
        self.cF[i, slot] = cF
        if ti.static(self.no_slip):
            if self.state.phase[j] != FLUID:
                w = cF * self.state.v[j].dot(xij) * xij
                for d in ti.static(range(3)):
                    acc[d] += w[d]
        for a in ti.static(range(3)):
            for b in ti.static(range(3)):
                acc[3 + 3 * a + b] += cF * xij[a] * xij[b]

    # ---------------------------------------------------------------- setup
    @ti.kernel
    def _setup(self, n: ti.i32, dt: float, tol: ti.f64, tol_max: ti.f64, rel2: ti.f64,
               scale: ti.f64, min_iter: ti.i32, max_iter: ti.i32) -> ti.types.vector(4, ti.f64):
        """rhs = v* - dt sum_b (wall velocity term); B^-1; x0 = v* + last change; the PCG from
        r0 = rhs - A x0, its error |r|^2 / |rhs|^2 (ref = |rhs|^2)."""
        self.cg.reset()
        self.dt[None] = dt
        for slot in range(n):
            i = self.fl.index[slot]
            if self.state.phase[i] == FLUID:
                acc = ti.Vector.zero(float, 12)
                self.grid.for_each_listed(i, self._setup_task, acc)
                rhs = self.state.v[i] - dt * ti.Vector([acc[0], acc[1], acc[2]])
                self.rhs[i] = rhs
                self.cg.term[i] = rhs.norm_sqr()
                B = ti.Matrix([[acc[3], acc[4], acc[5]], [acc[6], acc[7], acc[8]],
                               [acc[9], acc[10], acc[11]]])
                self.Binv[i] = (ti.Matrix.identity(float, 3) - dt * B).inverse()
                self.x[i] = self.state.v[i] + self.vdiff[i]
            else:
                self.rhs[i] = ti.Vector([0.0, 0.0, 0.0])
                self.x[i] = ti.Vector([0.0, 0.0, 0.0])
            self.p[i] = self.x[i]
        self.cg.sum.sum(self.cg.term, self.fl.total[None])
        ti.loop_config(serialize=True)
        for _ in range(1):
            self.cg.s.ref[None] = self.cg.sum.total[None]  # no fluid: r = 0, converged at once
        self.apply(n, 0, 0)  # Ap = A x0
        self.cg.begin_from(n, self.rhs, 0, tol, tol_max, rel2, scale, min_iter, max_iter)
        return self.cg.report()

    # ---------------------------------------------------------------- the PCG's protocol
    @ti.func
    def apply(self, n, skip, mode: ti.template()):
        """Ap = (I - dt B) p (B: the viscous sums of the fluid pairs)."""
        dt = self.dt[None]
        for slot in range(n):
            i = self.fl.index[slot]
            if skip == 0:
                if self.state.phase[i] == FLUID:
                    acc = ti.Vector([0.0, 0.0, 0.0])
                    self.grid.for_each_listed(i, self._apply_task, acc)
                    self.Ap[i] = self.p[i] - dt * acc
                else:
                    self.Ap[i] = ti.Vector([0.0, 0.0, 0.0])

    @ti.func
    def precondition(self, i, r, mode: ti.template()):
        return self.Binv[i] @ r

    @ti.func
    def advance(self, i, alpha, mode: ti.template()):
        self.x[i] += alpha * self.p[i]

    @ti.func
    def residual_term(self, i, r, mode: ti.template()):
        return r.norm_sqr()

    @ti.kernel
    def _finish(self, n: ti.i32):
        for slot in range(n):
            i = self.fl.index[slot]
            if self.state.phase[i] == FLUID:
                self.vdiff[i] = self.x[i] - self.state.v[i]
                self.state.v[i] = self.x[i]

    # ---------------------------------------------------------------- public
    def solve(self, dt: float) -> tuple[int, float]:
        """Replace the fluid velocities v* by the implicit viscous update; returns
        (iterations, relative residual)."""
        n = self.fl.n
        stop = Stop(tol=self.tol * self.tol, max_iter=self.max_iterations)
        iters, rel2, _ = self.cg.iterate(n, stop, 0, self._setup(n, dt, *stop))
        self._finish(n)
        self.stats["viscosity_iterations"] = iters
        self.stats["viscosity_residual"] = rel2 ** 0.5
        return iters, rel2 ** 0.5
