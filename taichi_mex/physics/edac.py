"""EDAC: entropically damped artificial compressibility (Ramachandran & Puri, Computers &
Fluids 179, 2019), free-surface form as in PySPH's ``EDACScheme`` (pb = 0), which the seed
paper used. Pressure is a transported variable, no equation of state:

    dp/dt = -rho c^2 div v + nu_edac lap p,     nu_edac = alpha h c / 8          (Eq. 10)
    dv/dt = -1/m_i sum_j (V_i^2 + V_j^2) p_ij grad W_ij + viscous + g

with V = 1/sum_j W_ij (number-density volume), p_ij = (rho_j p_i + rho_i p_j)/(rho_i + rho_j),
summation density rho_i = m_i sum_j W_ij, walls with hydrostatically extrapolated pressure
(Adami et al. 2012) and a ghost velocity for no-slip, and PySPH's PEC midpoint integrator.
"""

import math

from taichi_mex.backend import ti
from taichi_mex.core.reduce import BlockSum
from taichi_mex.core.shares import ThreadShares
from taichi_mex.core.state import FLUID, INLET, NOZZLE


@ti.data_oriented
class EDAC:
    def __init__(self, state, grid, kernel, viscosity, opts, gravity_m_s2: float, rho0: float):
        self.state = state
        self.grid = grid
        self.K = kernel
        self.visc = viscosity
        self.opts = opts
        self.rho0 = float(rho0)
        self.c = float(opts.sound_speed_m_s)
        self.h = kernel.h_smoothing_m
        self.eps = 0.01 * self.h * self.h
        self.nu_edac = opts.edac_alpha * self.h * self.c / 8.0
        self.g = (0.0, 0.0, -float(gravity_m_s2))
        self.clamp = bool(opts.clamp_wall_pressure)
        self.viscous = not (viscosity.model == "newtonian" and viscosity.eta_ref == 0.0)
        self.V = state.add("number_volume")  # m^3: 1 / sum_j W_ij (Hu & Adams volume)
        self.x0 = state.add("edac_x0", 3)
        self.v0 = state.add("edac_v0", 3)
        self.p0 = state.add("edac_p0")
        self.acc = state.add("acceleration", 3)
        self.dpdt = state.add("edac_dpdt")
        self.xdot = state.add("edac_xdot", 3)
        self.v_ghost = state.add("wall_ghost_velocity", 3)
        self.extremes = (0.0, 0.0)  # fastest speed, largest acceleration at the last evaluation
        self.reduce = BlockSum(state.capacity)
        self.scratch = ti.field(float, shape=state.capacity)
        self.scratch2 = ti.field(float, shape=state.capacity)
        self.scratch3 = ti.field(float, shape=state.capacity)
        # the rows each pass works on, listed at every neighbour rebuild (core/shares.py): the
        # fluid, and the walls that melt sees (the others have no list and are never read)
        self.fluid_rows = ThreadShares(state.capacity)
        self.wall_rows = ThreadShares(state.capacity)
        self._rows_listed_at = -1  # the grid's rebuild count they were listed at

    # ------------------------------------------------------------------ time step
    def time_step(self, nu_max: float) -> tuple[float, dict]:
        """Largest stable dt and each limit (s): CFL, viscous, force (PySPH's criteria),
        from the extremes the last evaluation returned."""
        vmax, amax = self.extremes
        limits = {"cfl": self.opts.cfl * self.h / (self.c + vmax)}
        if nu_max > 0:
            limits["viscous"] = 0.125 * self.h * self.h / nu_max
        if amax > 0:
            limits["force"] = 0.25 * math.sqrt(self.h / amax)
        return min(limits.values()), limits

    # ------------------------------------------------------------------ PEC stages
    @ti.kernel
    def predict(self, n: ti.i32, half_dt: float, t_eval: float) -> float:
        """Keep x0, v0, p0; move fluid to t + dt/2 with the last rates (EDACStep.stage1).
        Returns the largest fluid displacement since the last neighbour-list rebuild."""
        # one loop: copying, moving and measuring in three would read the fields three times
        for i in range(n):
            self.x0[i] = self.state.x[i]
            self.v0[i] = self.state.v[i]
            self.p0[i] = self.state.p[i]
            self._advance(i, half_dt, t_eval)
            self.scratch[i] = self.grid.displacement(i) if self.state.phase[i] == FLUID else 0.0
        self.reduce.max(self.scratch, n)
        return ti.cast(self.reduce.total[None], float)

    @ti.func
    def _advance(self, i, dt, t_eval):
        # Melt released by the inlet after the last evaluation has no rates yet: it keeps
        # its inflow velocity and feels gravity only until the next evaluation. (dt = 0: no-op.)
        if dt > 0.0 and self.state.phase[i] == FLUID:
            xd = self.xdot[i]
            a = self.acc[i]
            dp = self.dpdt[i]
            if self.state.born[i] > t_eval:
                xd = self.v0[i]
                a = ti.Vector(self.g)
                dp = 0.0
            self.state.x[i] = self.x0[i] + dt * xd
            self.state.v[i] = self.v0[i] + dt * a
            self.state.p[i] = self.p0[i] + dt * dp

    def evaluate(self, correct_dt: float = 0.0, t_eval: float = 0.0) -> int:
        """Rates at the current state; with correct_dt > 0 also the corrector step
        (EDACStep.stage2). Returns the number of non-finite fluid particles."""
        if self._rows_listed_at != self.grid.rebuilds:
            nf, nw = (int(v) for v in self._list_rows(self.state.n))
            self.fluid_rows.split(nf)
            self.wall_rows.split(nw)
            self._rows_listed_at = self.grid.rebuilds
        out = self._evaluate(self.state.n, correct_dt, t_eval)
        self.extremes = (float(out[0]), float(out[1]))
        return int(out[2])

    @ti.kernel
    def _list_rows(self, n: ti.i32) -> ti.types.vector(2, ti.i32):
        nf = 0
        nw = 0
        ti.loop_config(serialize=True)
        for i in range(n):
            work = self.grid.n_nbr[i]  # the density pass walks the whole list
            if self.state.phase[i] == FLUID:
                self.fluid_rows.rows[nf] = i
                self.fluid_rows.weight[nf] = work
                nf += 1
            elif work > 0:
                self.wall_rows.rows[nw] = i
                self.wall_rows.weight[nw] = work
                nw += 1
            else:  # no melt sees it: what the density and wall passes gave it when they ran
                self.V[i] = 1.0 / self.K.W0  # over every particle (its output stays the same)
                self.state.rho[i] = self.rho0
                self.state.p[i] = 0.0
                self.v_ghost[i] = self.state.v[i]
        return ti.Vector([nf, nw])

    @ti.kernel
    def _evaluate(self, n: ti.i32, dt: float, t_eval: float) -> ti.types.vector(3, float):
        self._density()
        self._walls()
        self._rates()
        for i in range(n):
            self._advance(i, dt, t_eval)
            ph = self.state.phase[i]
            s = 0.0
            a = 0.0
            bad = 0.0
            if ph == FLUID:
                s = self.state.v[i].norm()
                a = self.acc[i].norm()
                if ti.math.isnan(s) or ti.math.isinf(s):
                    s = 0.0
                    bad = 1.0
            elif ph == INLET or ph == NOZZLE:
                s = self.state.v[i].norm()
            self.scratch[i] = s
            self.scratch2[i] = a
            self.scratch3[i] = bad
        self.reduce.max(self.scratch, n)
        vmax = ti.cast(self.reduce.total[None], float)
        self.reduce.max(self.scratch2, n)
        amax = ti.cast(self.reduce.total[None], float)
        self.reduce.sum(self.scratch3, n)
        return ti.Vector([vmax, amax, ti.cast(self.reduce.total[None], float)])

    @ti.func
    def _density_task(self, i, j, xij, acc: ti.template()):
        acc += self.K.W(xij.norm())

    @ti.func
    def _number_density(self, i):
        """sum_j W_ij (with W(0)), and V_i from it. Also sorts i's list so that the wall and
        rate passes below, at the same positions, visit only the neighbours within the support."""
        acc = self.K.W0
        self.grid.for_each_neighbour_partitioning(i, self._density_task, acc)
        self.V[i] = 1.0 / acc
        return acc

    @ti.func
    def _density(self):
        for k in range(self.fluid_rows.span[None]):
            i = self.fluid_rows.row(k)
            if i >= 0:
                self.state.rho[i] = self.state.m[i] * self._number_density(i)
        for k in range(self.wall_rows.span[None]):
            i = self.wall_rows.row(k)
            if i >= 0:
                self._number_density(i)
                self.state.rho[i] = self.rho0

    @ti.func
    def _wall_task(self, i, j, xij, acc: ti.template()):
        if self.state.phase[j] == FLUID:
            w = self.K.W(xij.norm())
            g = ti.Vector(self.g)
            acc[0] += w
            acc[1] += (self.state.p[j] + self.state.rho[j] * g.dot(xij)) * w
            for d in ti.static(range(3)):
                acc[2 + d] += self.state.v[j][d] * w

    @ti.func
    def _walls(self):
        for k in range(self.wall_rows.span[None]):
            i = self.wall_rows.row(k)
            if i >= 0:
                acc = ti.Vector([0.0, 0.0, 0.0, 0.0, 0.0])
                self.grid.for_each_support_neighbour(i, self._wall_task, acc)
                vw = self.state.v[i]
                p = 0.0
                vg = vw
                if acc[0] > 1e-12 * self.K.W0:
                    p = acc[1] / acc[0]
                    vf = ti.Vector([acc[2], acc[3], acc[4]]) / acc[0]
                    vg = 2.0 * vw - vf
                if ti.static(self.clamp):
                    p = ti.max(p, 0.0)
                self.state.p[i] = p
                self.v_ghost[i] = vg

    @ti.func
    def _rate_task(self, i, j, xij, acc: ti.template()):
        st = self.state
        r2 = xij.norm_sqr()
        gw = self.K.F(ti.sqrt(r2)) * xij
        Vi = self.V[i]
        Vj = self.V[j]
        vol2 = Vi * Vi + Vj * Vj
        rho_i = st.rho[i]
        rho_j = st.rho[j]
        p_i = st.p[i]
        p_j = st.p[j]
        p_ij = (rho_j * p_i + rho_i * p_j) / (rho_i + rho_j)
        a = -vol2 * p_ij * gw
        lap = vol2 * xij.dot(gw) / (r2 + self.eps)
        vij = st.v[i] - st.v[j]
        if ti.static(self.viscous):  # PySPH also drops the term for nu = 0
            eta_i = self.visc.eta_of(i)
            if st.phase[j] == FLUID:
                eta_j = self.visc.eta_of(j)
                a += lap * (2.0 * eta_i * eta_j / (eta_i + eta_j + 1e-30)) * vij
            else:
                a += lap * eta_i * (st.v[i] - self.v_ghost[j])
        eta_e = 2.0 * self.nu_edac * rho_i * rho_j / (rho_i + rho_j)
        dp = (rho_i / rho_j) * self.c * self.c * st.m[j] * vij.dot(gw) * st.m[i] \
            + lap * eta_e * (p_i - p_j)
        for d in ti.static(range(3)):
            acc[d] += a[d]
        acc[3] += dp

    @ti.func
    def _rates(self):
        for k in range(self.fluid_rows.span[None]):
            i = self.fluid_rows.row(k)
            if i >= 0:
                acc = ti.Vector([0.0, 0.0, 0.0, 0.0])
                self.grid.for_each_support_neighbour(i, self._rate_task, acc)
                inv_m = 1.0 / self.state.m[i]
                self.acc[i] = ti.Vector([acc[0], acc[1], acc[2]]) * inv_m + ti.Vector(self.g)
                self.dpdt[i] = acc[3] * inv_m
                self.xdot[i] = self.state.v[i]
