"""Free-surface detection (Marrone et al., J. Comput. Phys. 229, 2010; Doring 2005).

lambda_i is the smallest eigenvalue of the renormalisation matrix (Randles & Libersky 1996)

    L_i = sum_j V_j (x_j - x_i) (x) grad_i W_ij        (paper Eq. 7)

which is the identity inside the melt and drops towards 0 as the support empties. Marrone's
two-step test marks a particle as free surface when lambda_i <= 0.2, and for
0.2 < lambda_i <= 0.75 when its 'umbrella' scan region along the outward normal
n_i = -L_i^-1 sum_j V_j grad W_ij is empty of neighbours. Boundary particles count as
neighbours, so melt touching the plate or the nozzle is not a free surface there.

The same neighbour pass gives what the heat losses need: the area of free surface each
particle represents (see :meth:`SurfaceDetector.areas`), by the seed paper's eigenvalue rule
(Eq. 6-8) or by the calibrated colour gradient, our default.
"""

import math

import numpy as np

from taichi_mex.backend import ti
from taichi_mex.core.state import FLUID, SOLID


@ti.data_oriented
class SurfaceDetector:
    """Free-surface flags, normals and areas of the particle state (lattice spacing
    spacing_m, m). The neighbour grid and kernel: here or later through :meth:`attach`."""

    def __init__(self, state, spacing_m: float, grid=None, kernel=None):
        st = state
        self.state = st
        self.grid = grid
        self.K = kernel
        self.lam = st.add("surface_lambda")
        self.normal = st.add("surface_normal", 3)
        self.flag = st.add("free_surface", dtype=ti.i32)  # 1 free surface, 2 next to it, 0 interior
        self.V = float(spacing_m) ** 3
        # scratch, valid right after update(): Shepard sum c_i = sum_j V_j W_ij (self
        # included) and |grad c_i| = |sum_j V_j grad W_ij|, for the colour-gradient area
        self.shepard = ti.field(float, shape=st.capacity)
        self.grad_norm = ti.field(float, shape=st.capacity)
        self._calibration = None
        self._updated_at = None  # grid.rebuilds when update() last ran

    def attach(self, grid, kernel):
        self.grid = grid
        self.K = kernel

    def update(self) -> None:
        n = self.state.n
        self._lambda(n)
        self._scan(n)
        self._near(n)
        self._updated_at = self.grid.rebuilds

    def current(self) -> None:
        """update() unless it already ran since the neighbour lists were last rebuilt: within
        a step the heat's surface areas and the coupled solve's density source read the same
        flags, at the positions the lists were built from."""
        if self._updated_at != self.grid.rebuilds:
            self.update()

    @ti.func
    def _L_task(self, i, j, xij, acc: ti.template()):
        F = self.K.F(xij.norm())
        # (x_j - x_i) (x) grad_i W_ij = -F xij (x) xij
        for a in ti.static(range(3)):
            for b in ti.static(range(3)):
                acc[a, b] -= self.V * F * xij[a] * xij[b]
            acc[3, a] += self.V * F * xij[a]  # row 3 collects sum_j V_j grad W_ij
        acc[4, 0] += self.V * self.K.W(xij.norm())  # row 4: the Shepard sum

    @ti.kernel
    def _lambda(self, n: ti.i32):
        for i in range(n):
            ph = self.state.phase[i]
            if ph == FLUID or ph == SOLID:
                acc = ti.Matrix.zero(float, 5, 3)
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
                self.shepard[i] = acc[4, 0] + self.V * self.K.W0
                self.grad_norm[i] = g.norm()
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


    # ------------------------------------------------------------------ free-surface areas
    def areas(self, out, method: str) -> None:
        """Free-surface area (m^2) each melt particle represents, into the field ``out``
        (0 for interior and wall particles). Call right after :meth:`update`.

        * ``eigenvalue``, the seed paper's rule: A = (1 - 4 lambda / 3) A_max for
          lambda < 0.75, A_max = 6 V^(2/3) (Eq. 6, 8). Linear in lambda, it gives a flat face
          about twice its area (lambda ~ 0.5 there), the overestimate the paper reports.
        * ``colour_gradient`` (default), on free-surface particles only (Marrone's test above):

              A_i = V^(2/3) [ |grad c_i| / (c_i a_face) + C_crease kappa_i ],
              kappa_i = sum_{j on the surface} V_j W_ij (1 - n_i . n_j) / c_i

          with c_i the Shepard sum, grad c_i = sum_j V_j grad W_ij. Summed over the particles
          of a body, V |grad c| weights each piece of surface by the fraction of the kernel
          inside the body there (1/2 on a face, less along edges and corners); dividing by
          c_i undoes most of that, and a_face (a flat lattice face) makes a face exact.
          Any smooth estimate still rounds a sharp edge off; the crease term, zero on a
          flat face and small on a gently curved one, adds that missing area where the
          normals of neighbouring surface particles turn, with C_crease fitted so that a
          square lattice rod has its exact perimeter. Corners and whole cubes are then a
          test, not a fit (tests/test_thermal.py).
        """
        n = self.state.n
        if method == "eigenvalue":
            self._area_eigenvalue(n, out, 6.0 * self.V ** (2.0 / 3.0))
        elif method == "colour_gradient":
            dx = self.V ** (1.0 / 3.0)
            if self._calibration is None:
                self._calibration = colour_calibration(self.K.kind, self.K.H / dx)
            a_face, c_crease = self._calibration
            self._area_colour(n, out, a_face / dx, c_crease, dx * dx)
        else:
            raise ValueError(f"unknown surface-area method {method!r}")

    @ti.kernel
    def _area_eigenvalue(self, n: ti.i32, out: ti.template(), a_max: float):
        for i in range(n):
            a = 0.0
            ph = self.state.phase[i]
            if (ph == FLUID or ph == SOLID) and self.lam[i] < 0.75:
                a = (1.0 - 4.0 / 3.0 * ti.max(self.lam[i], 0.0)) * a_max  # Eq. 8
            out[i] = a

    @ti.func
    def _crease_task(self, i, j, xij, acc: ti.template()):
        if self.flag[j] == 1:
            acc += self.V * self.K.W(xij.norm()) * (1.0 - self.normal[i].dot(self.normal[j]))

    @ti.kernel
    def _area_colour(self, n: ti.i32, out: ti.template(), a_face: float, c_crease: float,
                     a_unit: float):
        for i in range(n):
            a = 0.0
            if self.flag[i] == 1:  # set for melt particles only
                crease = 0.0
                self.grid.for_each_neighbour(i, self._crease_task, crease)
                c = self.shepard[i]
                a = a_unit * (self.grad_norm[i] / (c * a_face) + c_crease * crease / c)
            out[i] = a


_CALIBRATIONS: dict = {}


def colour_calibration(kind: str, support_factor: float) -> tuple[float, float]:
    """(a_face, C_crease) of the colour-gradient area for a kernel, in units of the spacing.

    Computed on a unit-spacing lattice rod (a square cross-section, long enough that its
    middle slice and that slice's neighbours see no end), with exactly the quantities the
    Taichi kernels above compute: a_face = |grad c| / c of the particle at the middle of a
    face; C_crease such that the middle slice's surface particles sum to the perimeter.
    """
    key = (kind, round(float(support_factor), 9))
    if key in _CALIBRATIONS:
        return _CALIBRATIONS[key]
    from taichi_mex.core.kernels import Kernel

    K = Kernel(kind, support_factor)
    H = K.H
    reach = int(math.ceil(H))
    n_side = 2 * reach + 5
    n_long = 4 * reach + 1
    I, J, Kz = np.meshgrid(np.arange(n_side), np.arange(n_side), np.arange(n_long), indexing="ij")
    x = np.stack([I.ravel(), J.ravel(), Kz.ravel()], axis=1).astype(np.float64)
    ring = (np.minimum(x[:, 0], x[:, 1]) == 0) | (np.maximum(x[:, 0], x[:, 1]) == n_side - 1)
    mid = 2 * reach
    near = np.nonzero(np.abs(x[:, 2] - mid) <= reach)[0]
    eps = 1e-6

    def F(r):  # (dW/dr) / r, as kernels.Kernel.F
        return (K.W_np(r + eps) - K.W_np(r - eps)) / (2.0 * eps * r)

    c = {}
    grad = {}
    normal = {}
    for i in near:
        xij = x[i] - x
        r = np.linalg.norm(xij, axis=1)
        m = (r > 0) & (r < H)
        f = F(r[m])
        L = -(f[:, None, None] * xij[m][:, :, None] * xij[m][:, None, :]).sum(axis=0)
        g = (f[:, None] * xij[m]).sum(axis=0)
        nrm = -np.linalg.solve(L, g) if abs(np.linalg.det(L)) > 1e-6 else -g
        normal[i] = nrm / max(np.linalg.norm(nrm), 1e-12)
        c[i] = K.W0 + K.W_np(r[m]).sum()
        grad[i] = np.linalg.norm(g)
    slice_ring = [i for i in near if ring[i] and x[i, 2] == mid]
    face = next(i for i in slice_ring if x[i, 0] == 0 and x[i, 1] == n_side // 2)
    a_face = grad[face] / c[face]
    smooth = 0.0
    crease = 0.0
    for i in slice_ring:
        xij = x[i] - x
        r = np.linalg.norm(xij, axis=1)
        js = np.nonzero((r > 0) & (r < H) & ring)[0]
        crease += sum(K.W_np(r[j]) * (1.0 - normal[i] @ normal[j]) for j in js) / c[i]
        smooth += grad[i] / c[i] / a_face
    c_crease = (4.0 * n_side - smooth) / crease
    _CALIBRATIONS[key] = (float(a_face), float(c_crease))
    return _CALIBRATIONS[key]


def interior_mask(surface: SurfaceDetector) -> np.ndarray:
    """Fluid particles whose whole kernel support is melt or wall (no free surface in it), in
    the order of the surface detector's state."""
    surface.update()
    st = surface.state
    phase = st.phase.to_numpy()[: st.n]
    flag = surface.flag.to_numpy()[: st.n]
    return flag[phase == FLUID] == 0
