"""Free-surface detection (Marrone et al., J. Comput. Phys. 229, 2010; Doring 2005).

lambda_i is the smallest eigenvalue of the renormalisation matrix (Randles & Libersky 1996)

    L_i = sum_j V_j (x_j - x_i) (x) grad_i W_ij        (paper Eq. 7)

which is the identity inside the melt and drops towards 0 as the support empties. Marrone's
two-step test marks a particle as free surface when lambda_i <= 0.2, and for
0.2 < lambda_i <= 0.75 when its 'umbrella' scan region along the outward normal
n_i = -L_i^-1 sum_j V_j grad W_ij is empty of neighbours. Boundary particles count as
neighbours, so melt touching the plate or the nozzle is not a free surface there.
"""

import numpy as np

from ..backend import ti
from ..state import FLUID, SOLID


@ti.data_oriented
class SurfaceDetector:
    def __init__(self, sim):
        self.sim = sim
        st = sim.state
        self.state = st
        self.grid = None
        self.K = None
        self.lam = st.add("surface_lambda")
        self.normal = st.add("surface_normal", 3)
        self.flag = st.add("free_surface", dtype=ti.i32)  # 1 free surface, 2 next to it, 0 interior
        self.V = sim.run_opts.spacing_m ** 3

    def attach(self, grid, kernel):
        self.grid = grid
        self.K = kernel

    def update(self) -> None:
        n = self.state.n
        self._lambda(n)
        self._scan(n)
        self._near(n)

    @ti.func
    def _L_task(self, i, j, xij, acc: ti.template()):
        F = self.K.F(xij.norm())
        # (x_j - x_i) (x) grad_i W_ij = -F xij (x) xij
        for a in ti.static(range(3)):
            for b in ti.static(range(3)):
                acc[a, b] -= self.V * F * xij[a] * xij[b]
            acc[3, a] += self.V * F * xij[a]  # row 3 collects sum_j V_j grad W_ij

    @ti.kernel
    def _lambda(self, n: ti.i32):
        for i in range(n):
            ph = self.state.phase[i]
            if ph == FLUID or ph == SOLID:
                acc = ti.Matrix.zero(float, 4, 3)
                self.grid.for_each_neighbour(i, self._L_task, acc)
                L = ti.Matrix([[acc[a, b] for b in range(3)] for a in range(3)])
                Ls = 0.5 * (L + L.transpose())
                eig, _ = ti.sym_eig(Ls)
                lam = ti.min(eig[0], eig[1], eig[2])
                g = ti.Vector([acc[3, 0], acc[3, 1], acc[3, 2]])
                nrm = ti.Vector([0.0, 0.0, 0.0])
                if ti.abs(L.determinant()) > 1e-6:
                    nrm = -(L.inverse() @ g)
                else:
                    nrm = -g
                if nrm.norm() > 1e-12:
                    nrm = nrm.normalized()
                self.lam[i] = lam
                self.normal[i] = nrm
            else:
                self.lam[i] = 1.0
                self.normal[i] = ti.Vector([0.0, 0.0, 0.0])

    @ti.func
    def _scan_task(self, i, j, xij, acc: ti.template()):
        # Marrone's umbrella, in its cone form: any neighbour within 45 degrees of the outward
        # normal means the particle is covered on that side, hence not on the free surface
        xji = -xij
        n = self.normal[i]
        r = xji.norm()
        if r > 0 and xji.dot(n) > 0.70710678 * r:
            acc += 1

    @ti.kernel
    def _scan(self, n: ti.i32):
        for i in range(n):
            ph = self.state.phase[i]
            f = 0
            if ph == FLUID or ph == SOLID:
                lam = self.lam[i]
                if lam <= 0.2:
                    f = 1
                elif lam <= 0.75:
                    acc = 0
                    self.grid.for_each_neighbour(i, self._scan_task, acc)
                    if acc == 0:
                        f = 1
            self.flag[i] = f

    @ti.func
    def _near_task(self, i, j, xij, acc: ti.template()):
        if self.flag[j] == 1:
            acc += 1

    @ti.kernel
    def _near(self, n: ti.i32):
        for i in range(n):
            if self.flag[i] == 0 and (self.state.phase[i] == FLUID or self.state.phase[i] == SOLID):
                acc = 0
                self.grid.for_each_neighbour(i, self._near_task, acc)
                if acc > 0:
                    self.flag[i] = 2


def interior_mask(sim) -> np.ndarray:
    """Fluid particles whose whole kernel support is melt or wall (no free surface in it)."""
    sim.surface.update()
    phase = sim.state.phase.to_numpy()[: sim.state.n]
    flag = sim.surface.flag.to_numpy()[: sim.state.n]
    return flag[phase == FLUID] == 0
