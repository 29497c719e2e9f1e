"""DFSPH: divergence-free SPH (Bender & Koschier, SCA 2015; IEEE TVCG 23(3), 2017).

Each step makes two implicit pressure corrections of the velocity,

    v_i <- v_i - dt G(k)_i,   G(k)_i = sum_j V_j (k_i + k_j) grad W_ij + sum_b V_b k_i grad W_ib

(k_i = p_i / rho_i * rho0 / rho_i: the symmetric SPH pressure gradient with Akinci et al.'s
(2012) pressure mirroring at walls), chosen so that the discrete divergence
D(u)_i = sum_j V_j (u_i - u_j) . grad W_ij + sum_b V_b u_i . grad W_ib of the correction
cancels a source:

* divergence solve (Alg. 2): D(G k) = d / dt with d = D(v) (velocity made divergence free);
* constant-density solve (Alg. 3): D(G k) = (rho*_i / rho0 - 1) / dt^2 with the predicted
  density rho*_i = rho_i + dt rho0 D(v) (positions made incompressible).

D and G are adjoint, so A = D G is symmetric positive semi-definite. The papers relax it
with Jacobi sweeps using the diagonal factor alpha_i = 1 / (sum_j |V_j grad W_ij|^2 +
|sum_j V_j grad W_ij + sum_b V_b grad W_ib|^2), clamping both sources to compression so that
free-surface particles (partial kernel support) are not pulled back. Inside the melt that
clamp lets the viscous flow open voids that nothing closes, and with tension allowed Jacobi
may oscillate; so we solve the same system by conjugate gradients (the shared ``core.pcg``)
preconditioned with alpha, clamping only at the free surface (particles whose kernel-weighted
neighbourhood centre is offset by more than surface_offset_h H (0.15), or with fewer than
surface_min_neighbours (20) neighbours, and whose source is an
expansion: their k is held at 0). The divergence solve is warm-started with half of the
previous step's k (Bender & Koschier, Sec. 4.4), the density solve is incremental
(``pressure_predictor``); both stop when the mean predicted error,
mean |source - A k| dt^2 (density) or dt (divergence), is below the tolerance.

This is the split solve (``--creeping-solve split``), for inertial flows: the hydrostatic
and shear scenes default to it, and a run whose melt may creep (nu dt / dx^2 >=
DFSPHOptions.creeping_diffusion at its largest step) is refused before it starts, since there
solving the viscosity before the pressure leaves an error the size of the solution
(physics/stokes.py, which solves them together and is the default). Until 2026-12-05 this
class also carried the creeping melt of prints, held together by stabilisers no paper gives:
tension in a difference form that does not conserve momentum, a cap on the speed at which
tension closed gaps, compression re-solves whose k stayed out of the pressure, the bore's
melt column as rows of the density solve. They acted only in creeping steps or on prints,
and are gone (spec.REMOVED_OPTIONS tells an old run description so); the hydrostatic
column's figures moved by rounding only (slope error 0.011420 -> 0.011424, 2026-12-05).

What stays of the stabilisers (DFSPHStabilisers) serves the inertial solve: the incremental
pressure (last step's summed k applied with gravity, van Kan 1986) losing 5 % a step, tension
inside the melt relaxed at 0.2 a step, and the free-surface flags. The papers' own form was
tried on 2026-12-05: sources clamped to compression everywhere, the density solve from zero
or from half of last step's k on the rows compressed now (as SPlisHSPlasH does), CG or
Jacobi. The hydrostatic column then held no pressure over whole layers: with the default
tolerances its slope was 23-53 % off rho g over those variants (warm-started with all of
last step's k on every row, it expanded by 19 %), and from a cold start at tolerances 500x
tighter the slope came within 3 % while the slab pressures stayed 27 % (mean) to 45 %
(largest) of rho g H off. Tried later that day: the coupled solve's continuity in the density
solve (the kernel sum's compression removed, the velocity's divergence held at zero both ways,
no surface flag, nothing forgotten), with or without Asai et al.'s relaxed expansion (J. Appl.
Math. 2012, 139583; free surface where the kernel sum is under 0.97, Koshizuka & Oka 1996).
Slope error 25 / 7.6 / 4.8 % at 1 / 0.667 / 0.5 mm (the stabilised solve: 1.1 / 0.0 / 1.6 %;
with Asai's relaxation 22 % at 1 mm and 4.6 % at 0.5 mm), and without that relaxation the
melt's kernel sums 0.14 % low at 0.5 mm: the summed pressure drifted along the floor (+45 %
there at 1 mm) while the velocities stayed divergence-free, and forgetting 5 % a step brought
the slope back to 2.9 %. Solved afresh each step instead (no memory), 19 % at
tolerances 10x tighter. The memory loss filters the pressure modes the solve cannot see.

Walls here (plate, nozzle, solidified melt, the melt column in the bore) are lattices at
the fluid's spacing and at least one support radius thick, so every wall particle stands
for one lattice cell: V_b = V0. Akinci's adaptive V_b = 1 / sum_k W_bk is meant for
single-layer surface samplings; on a thick wall it counts the wall's top layers up to twice.
Particle volumes are calibrated so that a rest lattice has rho = rho0 exactly.
"""

import numpy as np

from taichi_mex.backend import ti
from taichi_mex.core.pcg import PCG, Stop
from taichi_mex.core.state import FLUID, INLET, NOZZLE


def rest_volume(kernel, spacing_m: float) -> float:
    """1 / sum_j W_ij on the cubic lattice: the volume that makes a rest lattice exact."""
    m = int(np.ceil(kernel.H / spacing_m)) + 1
    r = np.arange(-m, m + 1) * spacing_m
    X, Y, Z = np.meshgrid(r, r, r, indexing="ij")
    d = np.sqrt(X**2 + Y**2 + Z**2)
    return float(1.0 / kernel.W_np(d).sum())


@ti.data_oriented
class DFSPH:
    """The two pressure solves. Every numerical knob is a field of ``DFSPHOptions`` (and of
    its ``stabilisers``); the reasons for their values are in the options' help and below.

    Measured reasons kept from the tuning (the single bead, before the coupled solve took
    creeping melt):
    * density_compression_only: with tension inside the melt and no relaxation it blew up in
      every variant (CG and Jacobi, omega 0.5-1, cubic and Wendland kernels).
    * tension_relaxation: tension's difference form blew up at 0.3, 0.4, 0.5 and 1.0
      (46-842 steps).
    """

    def __init__(self, state, grid, kernel, opts, rho0: float, spacing_m: float,
                 viscosity, rows):
        """rows: the FluidIndex the solves loop over; its owner updates it after every sort
        and phase change."""
        self.state = state
        st = opts.stabilisers
        # knobs read once: the kernels specialise on them (ti.static) when they first compile
        self.chunk = int(opts.cg_chunk)
        self.method = opts.method
        self.omega = float(opts.jacobi_omega)
        self.density_compression_only = bool(opts.density_compression_only)
        rel = opts.relative_residual
        self.rel2 = 1e300 if rel is None or opts.method != "cg" else float(rel) ** 2
        self.creeping_diffusion = float(opts.creeping_diffusion)
        self.tension_relaxation = float(st.tension_relaxation)
        self.surface_offset = float(st.surface_offset_h)
        self.surface_min_neighbours = int(st.surface_min_neighbours)
        self.divergence_tension = st.divergence_tension
        self.pressure_memory_loss = float(st.pressure_memory_loss)
        self.shifting = float(st.shifting)
        self.rows = rows
        self.viscosity = viscosity  # the melt's MeltViscosity: which steps are creeping
        self.grid = grid
        self.K = kernel
        self.opts = opts
        self.rho0 = float(rho0)
        self.dx = float(spacing_m)
        self.V0 = rest_volume(kernel, spacing_m)
        self.mass = self.rho0 * self.V0
        self.alpha = state.add("dfsph_factor")
        self.kappa = state.add("dfsph_kappa")  # summed k of the density solve (pressure-like)
        self.kappa_v = state.add("dfsph_kappa_v")  # summed k of the divergence solve, times dt
        self.n_count = state.add("neighbour_count", dtype=ti.i32)
        self.surface = state.add("dfsph_free_surface", dtype=ti.i32)
        cap = state.capacity
        self.b = ti.field(float, shape=cap)  # source (scaled to the system's right-hand side)
        self.active = ti.field(ti.i32, shape=cap)
        self.k = ti.field(float, shape=cap)  # this solve's k
        # the solves' CG; its error is the mean predicted error
        # (ref: the fluid count, Stop.scale: dt^2 or dt), its error_max the largest
        self.cg = PCG(self, self.rows, cap, dim=1, chunk=self.chunk, track_max=True)
        self.r, self.z, self.p, self.Ap = self.cg.r, self.cg.z, self.cg.p, self.cg.Ap
        self.term, self.sum = self.cg.term, self.cg.sum  # scratch for the solves' other sums
        self.Gp = ti.Vector.field(3, float, shape=cap)
        self.grad_c = ti.Vector.field(3, float, shape=cap)  # gradient of the kernel sum, for shifting
        self.rho_peak = ti.field(float, shape=())  # densest melt at x_n (set by prepare)
        self.step_dt = ti.field(float, shape=())  # this step's dt (solves)
        self.stats = {"density_iterations": 0, "divergence_iterations": 0}

    # ------------------------------------------------------------------ per step
    @ti.func
    def _density_task(self, i, j, xij, acc: ti.template()):
        w = self.K.W(xij.norm())
        acc[0] += self.V0 * w
        acc[1] += 1.0
        ph = self.state.phase[j]
        if ph == NOZZLE or ph == INLET:
            acc[5] += 1.0
        for d in ti.static(range(3)):
            acc[2 + d] -= w * xij[d]  # sum_j W_ij (x_j - x_i)

    @ti.func
    def _factor_task(self, i, j, xij, acc: ti.template()):
        gV = self.V0 * self.K.F(xij.norm()) * xij
        if self.state.phase[j] == FLUID:
            acc[0] += gV.dot(gV)  # only fluid neighbours move: the diagonal of D G
        for d in ti.static(range(3)):
            acc[1 + d] += gV[d]

    @ti.kernel
    def prepare(self, n: ti.i32):
        """Densities, neighbour counts, no-tension flags and alpha at x_n (no tension at the
        free surface, nor in melt touching a nozzle: there it would glue the melt to it)."""
        self.rho_peak[None] = 0.0
        for i in range(n):
            if self.state.phase[i] == FLUID:
                acc = ti.Vector([self.V0 * self.K.W0, 0.0, 0.0, 0.0, 0.0, 0.0])
                self.grid.for_each_neighbour(i, self._density_task, acc)
                self.state.rho[i] = self.rho0 * acc[0]
                ti.atomic_max(self.rho_peak[None], self.state.rho[i])
                self.n_count[i] = ti.cast(acc[1], ti.i32)
                offset = ti.Vector([acc[2], acc[3], acc[4]]) * self.V0 / acc[0]
                no_tension = (offset.norm() > self.surface_offset * self.K.H
                              or acc[1] < self.surface_min_neighbours or acc[5] > 0.0)
                self.surface[i] = 1 if no_tension else 0
                f = ti.Vector([0.0, 0.0, 0.0, 0.0])
                self.grid.for_each_neighbour(i, self._factor_task, f)
                s = f[0] + f[1] * f[1] + f[2] * f[2] + f[3] * f[3]
                self.alpha[i] = 1.0 / s if s > 0.0 else 0.0
                self.grad_c[i] = ti.Vector([f[1], f[2], f[3]])  # grad of C = sum_j V_j W_ij
            else:
                self.state.rho[i] = self.rho0
                self.alpha[i] = 0.0

    # ------------------------------------------------------------------ operators
    @ti.func
    def _grad_task(self, i, j, xij, acc: ti.template()):
        g = self.V0 * self.K.F(xij.norm()) * xij
        if self.state.phase[j] == FLUID:
            acc += (self.p[i] + self.p[j]) * g
        else:
            acc += self.p[i] * g

    @ti.func
    def _div_task(self, i, j, xij, acc: ti.template()):
        g = self.V0 * self.K.F(xij.norm()) * xij
        if self.state.phase[j] == FLUID:
            acc += (self.Gp[i] - self.Gp[j]).dot(g)
        else:
            acc += self.Gp[i].dot(g)

    @ti.func
    def _vdiv_task(self, i, j, xij, acc: ti.template()):
        g = self.V0 * self.K.F(xij.norm()) * xij
        acc += (self.state.v[i] - self.state.v[j]).dot(g)  # walls move: their v is set

    @ti.func
    def _apply(self, n, skip):
        """Gp = G(p) for fluid, Ap = D(Gp) on active particles (nothing when skip != 0)."""
        for slot in range(n):
            i = self.rows.index[slot]
            if skip == 0:
                g = ti.Vector([0.0, 0.0, 0.0])
                if self.state.phase[i] == FLUID:
                    self.grid.for_each_neighbour(i, self._grad_task, g)
                self.Gp[i] = g
        for slot in range(n):
            i = self.rows.index[slot]
            if skip == 0:
                a = 0.0
                if self.active[i] == 1:
                    self.grid.for_each_neighbour(i, self._div_task, a)
                self.Ap[i] = a

    @ti.func
    def _source(self, n, dt, density: ti.template()):
        """b = (rho*/rho0 - 1)/dt^2 or D(v)/dt, and r = b; fix the active set; term = |b| for
        the error."""
        for slot in range(n):
            i = self.rows.index[slot]
            if self.cg.s.done[None] != 0:
                continue
            b = 0.0
            act = 0
            if self.state.phase[i] == FLUID:
                div = 0.0
                self.grid.for_each_neighbour(i, self._vdiv_task, div)
                if ti.static(density):
                    b = (self.state.rho[i] / self.rho0 + dt * div - 1.0) / (dt * dt)
                else:
                    b = div / dt
                act = 1
                if ti.static(density):
                    if (self.surface[i] == 1 or ti.static(self.density_compression_only)) and b <= 0.0:
                        act = 0  # free surface opening up: no tension
                        b = 0.0
                    elif b < 0.0:
                        b *= self.tension_relaxation  # pull gaps shut over several steps
                else:
                    if self.n_count[i] < self.surface_min_neighbours:
                        act = 0  # too few neighbours for a divergence estimate
                        b = 0.0
                    elif ti.static(self.divergence_tension == "none") and b <= 0.0:
                        act = 0
                        b = 0.0
                    elif ti.static(self.divergence_tension == "interior") and self.surface[i] == 1 and b <= 0.0:
                        act = 0
                        b = 0.0
            self.b[i] = b
            self.r[i] = b  # r0 of the PCG (b = 0 off the active rows)
            self.active[i] = act
            self.term[i] = ti.abs(b)

    @ti.func
    def _kick(self, n, dt, kfield: ti.template()):
        """v -= dt G(kfield) for fluid (kfield copied into p first)."""
        for slot in range(n):
            i = self.rows.index[slot]
            self.p[i] = kfield[i]
        self._apply(n, 0)
        for slot in range(n):
            i = self.rows.index[slot]
            if self.state.phase[i] == FLUID:
                self.state.v[i] -= dt * self.Gp[i]

    @ti.kernel
    def pressure_predictor(self, n: ti.i32, n_rows: ti.i32, dt: float):
        """v -= dt G(kappa): last step's pressure, applied with gravity before the viscous solve
        (incremental pressure projection, van Kan 1986). Operator splitting otherwise lets
        gravity set the melt falling at g dt every step, which the implicit viscosity stops only
        after the step has moved it: a bead of 1000 Pa s then flattens at ~1 mm/s instead of
        creeping at rho g h^2 / eta ~ 1e-5 mm/s. A free-surface particle carries no pressure
        (p = 0 there). n_rows: the melt rows, an argument (a Python number read in a kernel is
        a constant of its compilation: rows.n read here kicked the first solve's rows only)."""
        for i in range(n):
            k = self.kappa[i] * (1.0 - self.pressure_memory_loss)
            if self.state.phase[i] != FLUID or self.surface[i] == 1:
                k = 0.0
            self.kappa[i] = k
        self._kick(n_rows, dt, self.kappa)
    # ------------------------------------------------------------------ CG
    @ti.kernel
    def _start(self, n: ti.i32, dt: float, density: ti.template(), tol: ti.f64, tol_max: ti.f64,
               rel2: ti.f64, scale: ti.f64, min_iter: ti.i32,
               max_iter: ti.i32) -> ti.types.vector(4, ti.f64):
        """Warm start, then the PCG from r0 = b (0 off the active rows: _source).

        The divergence solve starts from half of last step's k (Bender & Koschier), applied
        to the velocity before its source is taken, so r0 = b. The density solve is
        incremental: the whole of last step's pressure was already applied with gravity
        before the viscous solve (``pressure_predictor``), so it solves for the change only
        and adds it to kappa. The error's sum is divided by the fluid count (ref)."""
        self.cg.reset()
        self.step_dt[None] = dt
        for slot in range(n):
            i = self.rows.index[slot]
            self.term[i] = 1.0 if self.state.phase[i] == FLUID else 0.0
        self.sum.sum(self.term, self.rows.total[None])
        self.cg.s.ref[None] = ti.max(self.sum.total[None], 1.0)
        if ti.static(not density):
            self._source(n, dt, density)
            for slot in range(n):
                i = self.rows.index[slot]
                k = 0.0
                if self.active[i] == 1:
                    k = 0.5 * self.kappa_v[i] / dt
                self.k[i] = k
                self.kappa_v[i] = k
            self._kick(n, dt, self.k)
        self._source(n, dt, density)
        self.cg.begin(n, density, tol, tol_max, rel2, scale, min_iter, max_iter)
        return self.cg.report()

    # the PCG's protocol (mode: the density solve, else the divergence solve)
    @ti.func
    def apply(self, n, skip, mode: ti.template()):
        """Ap = D(G p) (Gp kept: advance moves the velocity with it)."""
        self._apply(n, skip)

    @ti.func
    def precondition(self, i, r, mode: ti.template()):
        return self.alpha[i] * r

    @ti.func
    def advance(self, i, a, mode: ti.template()):
        """k += a p, and the velocity with it: G is linear, so v -= dt a G(p) as we go."""
        if self.state.phase[i] == FLUID:
            self.state.v[i] -= self.step_dt[None] * a * self.Gp[i]
        if ti.static(mode):
            self.kappa[i] += a * self.p[i]
        else:
            self.kappa_v[i] += a * self.p[i]

    @ti.func
    def residual_term(self, i, r, mode: ti.template()):
        return ti.abs(r)  # times Stop.scale: the predicted density (divergence) error

    @ti.kernel
    def _jacobi(self, n: ti.i32, dt: float, density: ti.template(), tol: ti.f64,
                tol_max: ti.f64, rel2: ti.f64, scale: ti.f64, min_iter: ti.i32,
                max_iter: ti.i32) -> ti.types.vector(4, ti.f64):
        """Bender & Koschier's relaxed Jacobi sweeps (k = omega alpha b), `chunk` per launch,
        on the PCG's scalars and stopping rule (rel2 unused: no r.z here)."""
        for _step in ti.static(range(self.chunk)):
            for slot in range(n):
                i = self.rows.index[slot]
                if self.cg.s.done[None] == 0:
                    k = self.omega * self.alpha[i] * self.b[i]
                    self.p[i] = k
                    if ti.static(density):
                        self.kappa[i] += k
                    else:
                        self.kappa_v[i] += k
            for slot in range(n):
                i = self.rows.index[slot]
                if self.cg.s.done[None] == 0:
                    g = ti.Vector([0.0, 0.0, 0.0])
                    if self.state.phase[i] == FLUID:
                        self.grid.for_each_neighbour(i, self._grad_task, g)
                    self.Gp[i] = g
            for slot in range(n):
                i = self.rows.index[slot]
                if self.cg.s.done[None] == 0 and self.state.phase[i] == FLUID:
                    self.state.v[i] -= dt * self.Gp[i]
            self._source(n, dt, density)
            self.cg.record(tol, tol_max, scale, min_iter, max_iter)
        return self.cg.report()

    # ------------------------------------------------------------------ solves
    def _solve(self, dt: float, density: bool, tol: float, tol_local: float, min_iter: int,
               max_iter: int, rel2: float = 1e300) -> tuple[int, float]:
        n = self.rows.n
        # mean |residual| times dt^2 (density) or dt (divergence) = mean predicted error
        stop = Stop(tol=tol, tol_max=tol_local, rel2=rel2, scale=dt * dt if density else dt,
                    min_iter=min_iter, max_iter=max_iter)
        out = self._start(n, dt, density, *stop)
        if self.method == "jacobi":
            while out[3] == 0.0:
                out = self._jacobi(n, dt, density, *stop)
            iters, err, self.last_max_error = int(out[2]), float(out[0]), float(out[1])
        else:
            iters, err, self.last_max_error = self.cg.iterate(n, stop, density, out)
        return iters, err

    def creeping(self, dt: float) -> bool:
        """Every melt particle in the creeping regime this step (see creeping_diffusion)."""
        nu = self.viscosity.min_value() / self.rho0
        return nu * dt >= self.creeping_diffusion * self.dx * self.dx

    def divergence_solve(self, dt: float) -> tuple[int, float]:
        o = self.opts
        iters, err = self._solve(dt, False, o.max_divergence_error, o.max_divergence_error_local,
                                 0, o.max_iterations)
        self.stats["divergence_iterations"] = iters
        return iters, err

    def density_solve(self, dt: float) -> tuple[int, float]:
        o = self.opts
        iters, err = self._solve(dt, True, o.max_density_error, o.max_density_error_local,
                                 o.min_iterations, o.max_iterations, self.rel2)
        self.stats["density_iterations"] = iters
        return iters, err

    @ti.kernel
    def max_fluid_speed(self, n: ti.i32) -> float:
        vmax = 0.0
        for i in range(n):
            if self.state.phase[i] == FLUID:
                ti.atomic_max(vmax, self.state.v[i].norm())
        return vmax

    @ti.kernel
    def finish(self, n: ti.i32, dt: float, shift: float) -> ti.types.vector(2, float):
        """Pressure for output (p = kappa rho^2 / rho0), the divergence stiffness made
        dt-independent for the next warm start, fluid moved; returns (max fluid speed,
        non-finite fluid particles). No melt is removed or slowed here: a step whose melt
        moves too far is redone shorter by the caller, or the run stops.

        The density solve's k is pressure-like (the compression a step creates scales with
        dt^2); the divergence solve's k scales with 1/dt, so it is stored times dt.

        Particle shifting (Lind et al., J. Comput. Phys. 231, 2012): x += -D grad C with
        C = sum_j V_j W_ij and D = shift (m^2), at most a tenth of a spacing, tangential only at
        the free surface. The compression-only density solve cannot close the gaps that the
        nozzle opens when it shears and stretches the extrudate; shifting does. Lind et al.
        scale D with the flow speed; a creeping bead at rest behind the nozzle would then keep
        its gaps, so D is a fixed fraction of dx^2 per step (no shift on a uniform lattice)."""
        vmax = 0.0
        bad = 0.0
        for i in range(n):
            if self.state.phase[i] == FLUID:
                rho = self.state.rho[i]
                self.state.p[i] = self.kappa[i] * rho * rho / self.rho0
                self.kappa_v[i] *= dt
                dr = -shift * self.grad_c[i]
                if self.surface[i] == 1:
                    g = self.grad_c[i]
                    gg = g.norm_sqr()
                    if gg > 0.0:
                        dr -= dr.dot(g) / gg * g  # keep the free surface where it is
                lim = 0.1 * self.dx
                if dr.norm() > lim:
                    dr *= lim / dr.norm()
                self.state.x[i] += dt * self.state.v[i] + dr
                s = self.state.v[i].norm()
                if ti.math.isnan(s) or ti.math.isinf(s):
                    bad += 1.0
                else:
                    ti.atomic_max(vmax, s)
        return ti.Vector([vmax, bad])
