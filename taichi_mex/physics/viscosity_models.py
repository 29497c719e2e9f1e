"""Melt viscosity per particle: Newtonian, Arrhenius or Cross-WLF (Moldflow form).

    Arrhenius:  eta0(T) = eta_ref exp(E/R (1/T - 1/T_ref))
    Cross-WLF:  eta0(T) = D1 exp(-A1 (T - D2) / (A2 + T - D2)),
                eta(T, gdot) = eta0 / (1 + (eta0 gdot / tau*)^(1 - n))

Temperature enters only when the scene carries a temperature field; the shear rate only
for Cross-WLF (it is computed from the SPH velocity gradient by whoever owns ``shear_rate``).
``scale`` multiplies every value (creeping-flow scaling keeps ratios intact).
"""

from taichi_mex.backend import ti
from taichi_mex.core.state import FLUID


@ti.data_oriented
class MeltViscosity:
    def __init__(self, state, material, temperature=None, scale: float = 1.0):
        self.state = state
        self.model = material.viscosity_model
        self.eta_ref = float(material.viscosity_pa_s) * scale
        self.scale = float(scale)
        self.E_over_R = material.arrhenius_activation_j_mol / 8.314
        self.T_ref = material.arrhenius_reference_c + 273.15
        self.d1 = material.wlf_d1_pa_s * scale
        self.d2 = material.wlf_d2_k
        self.a1 = material.wlf_a1
        self.a2 = material.wlf_a2_k
        self.n_exp = material.cross_n
        self.tau = material.cross_tau_star_pa * scale
        self.T = temperature
        self.has_T = temperature is not None
        self.eta = state.add("viscosity")  # Pa s
        self._max_eta = ti.field(float, shape=())
        self._min_eta = ti.field(float, shape=())
        self.shear_rate = state.add("shear_rate") if self.model == "cross_wlf" else None
        if self.model != "newtonian" and temperature is None:
            # without heat the melt sits at the extrusion temperature
            self.T_const = material.extrusion_temperature_c + 273.15
        else:
            self.T_const = 0.0

    def attach(self, grid, kernel) -> None:
        """Neighbour access for the shear rate (Cross-WLF only)."""
        self.grid = grid
        self.K = kernel

    @property
    def is_constant(self) -> bool:
        return self.model == "newtonian"

    def max_value(self) -> float:
        """Upper bound used for explicit time-step limits (Pa s)."""
        if self.model == "newtonian":
            return self.eta_ref
        self._max_eta[None] = 0.0
        self._reduce_max(self.state.n)
        return float(self._max_eta[None])

    def min_value(self) -> float:
        """Lowest melt viscosity now (Pa s; the reference value while there is no melt)."""
        if self.model == "newtonian":
            return self.eta_ref
        self._min_eta[None] = float("inf")
        self._reduce_min(self.state.n)
        value = float(self._min_eta[None])
        return value if value < float("inf") else self.eta_ref

    @ti.func
    def eta_of(self, i):
        """Dynamic viscosity of particle i (Pa s); a constant for Newtonian melts."""
        value = self.eta_ref
        if ti.static(self.model != "newtonian"):
            value = self.eta[i]
        return value

    @ti.func
    def zero_shear(self, T_kelvin):
        value = self.eta_ref
        if ti.static(self.model == "arrhenius"):
            value = self.eta_ref * ti.exp(self.E_over_R * (1.0 / T_kelvin - 1.0 / self.T_ref))
        elif ti.static(self.model == "cross_wlf"):
            dT = T_kelvin - self.d2
            value = self.d1 * ti.exp(-self.a1 * dT / (self.a2 + dT))
        return value

    def update(self, n: int) -> None:
        if self.model == "cross_wlf":
            self._shear_rates(n)
        if self.model != "newtonian":
            self._update(n)

    @ti.func
    def _gradient_task(self, i, j, xij, acc: ti.template()):
        # SPH velocity gradient L_i = sum_j (m_j / rho_j) (v_j - v_i) (x) grad W_ij
        g = self.K.F(xij.norm()) * xij
        vol = self.state.m[j] / ti.max(self.state.rho[j], 1e-12)
        acc += vol * (self.state.v[j] - self.state.v[i]).outer_product(g)

    @ti.kernel
    def _shear_rates(self, n: ti.i32):
        """gdot_i = sqrt(2 D:D) with D the symmetric part of the velocity gradient (lagged one
        step: the implicit solve then sees a viscosity frozen over the step)."""
        for i in range(n):
            if self.state.phase[i] == FLUID:
                L = ti.Matrix.zero(float, 3, 3)
                self.grid.for_each_neighbour(i, self._gradient_task, L)
                D = 0.5 * (L + L.transpose())
                s = 0.0
                for a in ti.static(range(3)):
                    for b in ti.static(range(3)):
                        s += D[a, b] * D[a, b]
                self.shear_rate[i] = ti.sqrt(2.0 * s)

    @ti.kernel
    def _update(self, n: ti.i32):
        for i in range(n):
            if self.state.phase[i] == FLUID:
                T = self.T_const
                if ti.static(self.has_T):
                    T = self.T[i] + 273.15
                eta = self.zero_shear(T)
                if ti.static(self.model == "cross_wlf"):
                    eta = eta / (1.0 + (eta * self.shear_rate[i] / self.tau) ** (1.0 - self.n_exp))
                self.eta[i] = eta

    @ti.kernel
    def _reduce_min(self, n: ti.i32):
        for i in range(n):
            if self.state.phase[i] == FLUID:
                ti.atomic_min(self._min_eta[None], self.eta[i])

    @ti.kernel
    def _reduce_max(self, n: ti.i32):
        for i in range(n):
            if self.state.phase[i] == FLUID:
                ti.atomic_max(self._max_eta[None], self.eta[i])
