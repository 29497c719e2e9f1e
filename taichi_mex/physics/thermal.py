"""Heat: conduction between particles, convection and radiation at the free surface.

The seed paper's temperature equation (Eq. 5), per melt particle a:

    dT_a/dt = sum_b m_b / (c_a rho_a rho_b) 4 k_a k_b / (k_a + k_b) (T_a - T_b) x_ab . grad W_ab / |x_ab|^2
              + A_a h_c (T_A - T_a) / (m_a c_a) + A_a eps sigma (T_A^4 - T_a^4) / (m_a c_a)

The first term is Brookshaw's (1985) SPH Laplacian with Cleary & Monaghan's (J. Comput. Phys.
148, 1999) harmonic-mean conductivity (paper Eq. 2): each pair exchanges heat in proportion
to the temperature difference, so energy is conserved to round-off and a body with no
sources is insulated at its free surface without any boundary treatment. The others are
Newton's law of cooling (Eq. 4) and the Stefan-Boltzmann law (Eq. 3, temperatures in K),
applied through the free-surface area A_a each particle represents (physics/surface.py:
the paper's eigenvalue rule, Eq. 6-8, or our calibrated colour gradient).

c and k may depend on temperature (piecewise-linear tables in Material); the rate then uses
c(T_a) as a heat capacity, and k(T) of each particle in the harmonic mean.

Walls are isothermal: the build plate at the plate temperature, the nozzle and the melt in
its bore at the extrusion temperature. Steel (~50 W/m K) and brass (~110 W/m K) conduct
hundreds of times better than the melt (~0.1-0.2 W/m K), so a wall's conductivity is taken
as infinite: the pair factor 4 k_a k_b / (k_a + k_b) tends to 4 k_a, the limit in which the
wall side of the contact has no thermal resistance.

Forward Euler in time. With dt D_a <= 1, where D_a is the sum of the pair coefficients
(plus the linearised loss rate), the new temperature is a convex combination of the old
ones: no new extremes. The time step keeps dt D_max at ``SAFETY``.
"""

import numpy as np

from taichi_mex.backend import real_np_dtype, ti
from taichi_mex.errors import UserInputError
from taichi_mex.core.state import FLUID, INLET, NOZZLE, PLATE, SOLID, write_field

STEFAN_BOLTZMANN = 5.670374419e-8  # W / (m^2 K^4)
KELVIN = 273.15
#: dt * max_a D_a: 1 is the positivity limit of the explicit update; half of it leaves room
#: for D changing between steps (moving particles, temperature-dependent k and c)
SAFETY = 0.5


def _table(points, name: str):
    """Validated (T degC, value) points of a piecewise-linear property, or None."""
    if not points:
        return None
    try:
        pts = [(float(t), float(v)) for t, v in points]
    except (TypeError, ValueError):
        raise UserInputError(f"material {name} must be a list of (temperature degC, value) "
                             f"pairs, got {points!r}.") from None
    temps = [t for t, _ in pts]
    if any(b <= a for a, b in zip(temps, temps[1:])):
        raise UserInputError(f"material {name}: temperatures must increase, got {temps}.")
    if any(not v > 0 for _, v in pts):
        raise UserInputError(f"material {name}: values must be positive, got {pts}.")
    return tuple(temps), tuple(v for _, v in pts)


def _interpolator(table):
    """A ti.func T -> value, linear between the table's points and constant beyond them."""
    temps, values = table

    @ti.func
    def f(T):
        v = values[0]
        for k in ti.static(range(1, len(temps))):
            if T > temps[k - 1]:
                w = ti.min((T - temps[k - 1]) / (temps[k] - temps[k - 1]), 1.0)
                v = values[k - 1] + w * (values[k] - values[k - 1])
        return v

    return f


def lattice_coefficient_sum(kernel, spacing_m: float) -> float:
    """sum_b V_b (-F_ab) over a full cubic lattice (1/m^2): the diffusion operator's
    diagonal per unit of 2 k / (rho c) (F = (dW/dr)/r, see kernels.py)."""
    m = int(np.ceil(kernel.H / spacing_m)) + 1
    r = np.arange(-m, m + 1) * spacing_m
    X, Y, Z = np.meshgrid(r, r, r, indexing="ij")
    d = np.sqrt(X**2 + Y**2 + Z**2).ravel()
    d = d[(d > 0) & (d < kernel.H)]
    eps = 1e-9 * kernel.H
    F = (kernel.W_np(d + eps) - kernel.W_np(d - eps)) / (2.0 * eps * d)
    return float(-(F * spacing_m**3).sum())


def diffusion_dt_s(kernel, spacing_m: float, conductivity_w_mk: float, density_kg_m3: float,
                   specific_heat_j_kgk: float, wall_contact: bool = True) -> float:
    """Thermal diffusion limit of the explicit step on a rest lattice (s). With wall_contact
    the bound covers a particle whose neighbours are all isothermal walls (factor 4 k
    instead of 2 k): a safe first step before any rates were measured."""
    factor = 4.0 if wall_contact else 2.0
    D = factor * conductivity_w_mk / (density_kg_m3 * specific_heat_j_kgk) \
        * lattice_coefficient_sum(kernel, spacing_m)
    return SAFETY / D


@ti.data_oriented
class Thermal:
    """Temperatures of the particle state.

    state, kernel, spacing_m: the particles, the SPH kernel and the lattice spacing (m);
    material: the melt's Material; opts: ThermalOptions; clock: returns the current simulated
    time (s), for the glass-transition times. The neighbour grid and the free-surface detector
    exist only after this module (the viscosity reads ``T``): hand them over with
    :meth:`attach` before the first step."""

    def __init__(self, state, kernel, spacing_m: float, material, opts, clock):
        st = state
        self.state = st
        mat = material
        self.clock = clock
        self.K = kernel
        self.spacing_m = float(spacing_m)
        self.k0 = float(mat.conductivity_w_mk)
        self.c0 = float(mat.specific_heat_j_kgk)
        self.rho0 = float(mat.density_kg_m3)
        self.V0 = self.spacing_m ** 3
        self.k_table = _table(mat.conductivity_table, "conductivity_table")
        self.c_table = _table(mat.specific_heat_table, "specific_heat_table")
        self.T_extrusion = float(mat.extrusion_temperature_c)
        self.T_plate = float(opts.plate_temperature_c)
        self.T_glass = float(mat.glass_transition_c)
        self.T_ambient = float(opts.ambient_c)
        self.h_c = float(opts.convection_w_m2k)
        self.emissivity = 0.0 if opts.radiation_emissivity is None else float(opts.radiation_emissivity)
        if self.h_c < 0 or not 0 <= self.emissivity <= 1:
            raise UserInputError("Convection h_c must be >= 0 W/m^2/K and the emissivity in [0, 1]; "
                                 f"got {self.h_c} and {self.emissivity}.")
        self.losses = self.h_c > 0 or self.emissivity > 0
        self.method = opts.surface_method

        self.T = st.add("temperature")  #: degC (the viscosity model reads it)
        self.area = st.add("surface_area")  #: m^2 of free surface the particle represents
        #: time (s) since which the particle has stayed below the glass transition, -1 above it
        self.glass_since = st.add("glass_since")
        # scratch, rewritten every step before it is read: not carried through sorts
        self.dTdt = ti.field(float, shape=st.capacity)
        self.kappa = ti.field(float, shape=st.capacity) if self.k_table else None
        self.cp = ti.field(float, shape=st.capacity) if self.c_table else None
        self.has_k_table = self.k_table is not None
        self.has_c_table = self.c_table is not None
        self._k_of = _interpolator(self.k_table) if self.k_table else None
        self._c_of = _interpolator(self.c_table) if self.c_table else None

        self.grid = None  # the neighbour grid and the surface detector: attach()
        self.surface = None
        self._areas_at = None  # grid.rebuilds count when the areas were computed
        self._d_max = None  # largest D_a of the last step, 1/s
        st.on_append.append(self._on_append)

    def attach(self, grid, surface) -> None:
        """The neighbour grid and the free-surface detector (physics/surface.py)."""
        self.grid = grid
        self.surface = surface

    # ------------------------------------------------------------------ initial values
    def _default_temperature(self, phase: int) -> float:
        if phase in (FLUID, INLET, NOZZLE):
            return self.T_extrusion
        return self.T_plate  # the plate, and solid substrate resting on it

    def _on_append(self, sl: slice, phase: int) -> None:
        self.set_temperature(sl, self._default_temperature(phase))

    def set_temperature(self, sl: slice, value_c) -> None:
        """Temperature (degC) of the particles sl: a number, or one value per particle."""
        count = sl.stop - sl.start
        if count <= 0:
            return
        values = np.broadcast_to(np.asarray(value_c, dtype=np.float64), (count,))
        t_now = float(self.clock())
        since = np.where(values < self.T_glass, t_now, -1.0)
        dtype = real_np_dtype()
        write_field(self.T, sl.start, np.ascontiguousarray(values, dtype=dtype))
        write_field(self.glass_since, sl.start, np.ascontiguousarray(since, dtype=dtype))

    # ------------------------------------------------------------------ time step
    def dt_limits(self) -> dict:
        """{'thermal': s}: SAFETY / max_a D_a from the last step, or a rest-lattice bound
        before the first step."""
        if self._d_max is None or self._d_max <= 0:
            k_max = max(self.k_table[1]) if self.k_table else self.k0
            c_min = min(self.c_table[1]) if self.c_table else self.c0
            dt = diffusion_dt_s(self.K, self.spacing_m, k_max, self.rho0, c_min)
        else:
            dt = SAFETY / self._d_max
        return {"thermal": dt}

    def step(self, dt: float) -> None:
        """Advance temperatures by dt; call where neighbour lists and densities are current."""
        if self.losses and self._areas_at != self.grid.rebuilds:
            self.surface.current()
            self._areas()
        self._d_max = float(self._advance(self.state.n, dt, float(self.clock()) + dt))

    def update_areas(self) -> None:
        """Free-surface area per particle (the surface moves only as fast as the lists are
        rebuilt, so areas are refreshed with them)."""
        self.surface.update()
        self._areas()

    def _areas(self) -> None:
        """The areas from the surface's latest update."""
        self.surface.areas(self.area, self.method)
        self._areas_at = self.grid.rebuilds

    # ------------------------------------------------------------------ kernels
    @ti.func
    def conductivity(self, i):
        k = self.k0
        if ti.static(self.has_k_table):
            k = self.kappa[i]
        return k

    @ti.func
    def specific_heat(self, i):
        c = self.c0
        if ti.static(self.has_c_table):
            c = self.cp[i]
        return c

    @ti.func
    def _pair_task(self, i, j, xij, acc: ti.template()):
        st = self.state
        ki = self.conductivity(i)
        ph = st.phase[j]
        pair = 4.0 * ki  # isothermal wall: infinitely conductive side of the contact
        if ph != PLATE and ph != NOZZLE:
            kj = self.conductivity(j)
            pair = 4.0 * ki * kj / (ki + kj)  # Eq. 2
        rho_j = st.rho[j]
        Vj = self.V0
        if rho_j > 0.0:
            Vj = st.m[j] / rho_j
        # x_ab . grad W_ab / |x_ab|^2 = F(r) < 0: w >= 0 is heat per (kelvin * rho_a c_a)
        w = -Vj * pair * self.K.F(xij.norm())
        acc[0] += w * (self.T[j] - self.T[i])
        acc[1] += w

    @ti.kernel
    def _advance(self, n: ti.i32, dt: float, t_after: float) -> float:
        st = self.state
        if ti.static(self.has_k_table):
            for i in range(n):
                self.kappa[i] = self._k_of(self.T[i])
        if ti.static(self.has_c_table):
            for i in range(n):
                self.cp[i] = self._c_of(self.T[i])
        d_max = 0.0
        for i in range(n):
            ph = st.phase[i]
            rate = 0.0
            if ph == FLUID or ph == SOLID:
                acc = ti.Vector([0.0, 0.0])
                self.grid.for_each_neighbour(i, self._pair_task, acc)
                rho_i = st.rho[i]
                if rho_i <= 0.0:
                    rho_i = self.rho0
                rho_c = rho_i * self.specific_heat(i)
                rate = acc[0] / rho_c
                coeff = acc[1] / rho_c
                if ti.static(self.losses):
                    A = self.area[i]
                    if A > 0.0:
                        Ti = self.T[i]
                        mc = st.m[i] * self.specific_heat(i)
                        Tk = Ti + KELVIN
                        Tak = self.T_ambient + KELVIN
                        # Eq. 4 and Eq. 3 as heat sources (Eq. 5)
                        rate -= A * (self.h_c * (Ti - self.T_ambient)
                                     + self.emissivity * STEFAN_BOLTZMANN * (Tk**4 - Tak**4)) / mc
                        coeff += A * (self.h_c + 4.0 * self.emissivity * STEFAN_BOLTZMANN * Tk**3) / mc
                ti.atomic_max(d_max, coeff)
            self.dTdt[i] = rate
        for i in range(n):
            ph = st.phase[i]
            if ph == FLUID or ph == SOLID:
                T_new = self.T[i] + dt * self.dTdt[i]
                self.T[i] = T_new
                if T_new < self.T_glass:
                    if self.glass_since[i] < 0.0:
                        self.glass_since[i] = t_after
                else:
                    self.glass_since[i] = -1.0
        return d_max

    # ------------------------------------------------------------------ results
    def free_surface_areas(self) -> np.ndarray:
        """Areas (m^2) of all live particles, computed now with the current neighbour lists."""
        self.update_areas()
        return self.state.numpy("surface_area").astype(np.float64)

    def summary(self) -> dict:
        st = self.state
        phase = st.phase.to_numpy()[: st.n]
        melt = (phase == FLUID) | (phase == SOLID)
        out = {"surface_method": self.method,
               "thermal_dt_s": float(self.dt_limits()["thermal"])}
        if not melt.any():
            return out
        T = st.numpy("temperature")[melt].astype(np.float64)
        out["temperature_min_c"] = float(T.min())
        out["temperature_max_c"] = float(T.max())
        out["temperature_mean_c"] = float(T.mean())
        if self.losses:
            out["free_surface_area_m2"] = float(st.numpy("surface_area")[melt].astype(np.float64).sum())
        out.update(self._bead_cooling(melt))
        return out

    def _bead_cooling(self, melt: np.ndarray) -> dict:
        """Per bead: time from its last particle leaving the nozzle until all of it was
        below the glass transition (None while some of it is still above)."""
        st = self.state
        bead = st.bead.to_numpy()[: st.n][melt]
        if not (bead >= 0).any():
            return {}
        since = st.numpy("glass_since")[melt].astype(np.float64)
        born = st.numpy("birth_time")[melt].astype(np.float64)
        times = {}
        for b in np.unique(bead[bead >= 0]):
            sel = bead == b
            if (since[sel] < 0).any():
                times[str(int(b))] = None
            else:
                times[str(int(b))] = float(max(since[sel].max() - born[sel].max(), 0.0))
        cooled = [v for v in times.values() if v is not None]
        return {"glass_transition_c": self.T_glass,
                "bead_cooling_below_tg_s": times,
                "beads_cooled_below_tg": len(cooled),
                "bead_cooling_below_tg_max_s": max(cooled) if cooled else None}


__all__ = ["Thermal", "diffusion_dt_s", "lattice_coefficient_sum", "STEFAN_BOLTZMANN"]
