"""SPH smoothing kernels in 3D, written in terms of the support radius H (W = 0 for r >= H).

Both kernels expose ``W(r)`` and ``F(r) = (dW/dr)/r``, so that ``grad W(x) = F(|x|) x`` has
no division by r (F is finite at r = 0). ``h`` in the PySPH sense is H/2 for both.

* cubic spline (Monaghan 1992), normalised as in SPlisHSPlasH: sigma = 8/(pi H^3)
* Wendland C2 (Wendland 1995; Dehnen & Aly 2012): sigma = 21/(2 pi H^3), W = sigma (1-q)^4 (1+4q)
"""


import math

from taichi_mex.backend import ti

KERNELS = ("cubic", "wendland_c2")


@ti.data_oriented
class Kernel:
    def __init__(self, kind: str, support_radius_m: float):
        if kind not in KERNELS:
            raise ValueError(f"unknown kernel {kind!r}; choose one of {KERNELS}")
        self.kind = kind
        self.H = float(support_radius_m)
        H3 = self.H**3
        if kind == "cubic":
            self.sigma = 8.0 / (math.pi * H3)
            self.grad_sigma = 48.0 / (math.pi * H3)
        else:
            self.sigma = 21.0 / (2.0 * math.pi * H3)
            self.grad_sigma = self.sigma * 20.0
        self.W0 = self.sigma  # W(0) = sigma for both kernels

    @property
    def h_smoothing_m(self) -> float:
        """PySPH's smoothing length (support = 2h)."""
        return 0.5 * self.H

    @ti.func
    def W(self, r):
        q = r / self.H
        w = q * 0.0  # r's precision (the coupled solve evaluates in f64)
        if ti.static(self.kind == "cubic"):
            if q <= 0.5:
                w = self.sigma * (6.0 * q * q * (q - 1.0) + 1.0)
            elif q < 1.0:
                w = 2.0 * self.sigma * (1.0 - q) ** 3
        else:
            if q < 1.0:
                w = self.sigma * (1.0 - q) ** 4 * (1.0 + 4.0 * q)
        return w

    @ti.func
    def F(self, r):
        """(dW/dr)/r: multiply by the separation vector to get grad W."""
        q = r / self.H
        f = q * 0.0  # r's precision (the coupled solve evaluates in f64)
        if ti.static(self.kind == "cubic"):
            if q <= 0.5:
                f = self.grad_sigma * (3.0 * q - 2.0) / (self.H * self.H)
            elif q < 1.0:
                f = -self.grad_sigma * (1.0 - q) ** 2 / (self.H * self.H * q)
        else:
            if q < 1.0:
                f = -self.grad_sigma * (1.0 - q) ** 3 / (self.H * self.H)
        return f

    @ti.func
    def grad(self, xij):
        return self.F(xij.norm()) * xij

    # python-side evaluation for tests and estimates
    def W_np(self, r):
        import numpy as np

        q = np.asarray(r, dtype=np.float64) / self.H
        if self.kind == "cubic":
            return np.where(q <= 0.5, self.sigma * (6 * q**2 * (q - 1) + 1),
                            np.where(q < 1, 2 * self.sigma * np.clip(1 - q, 0, None) ** 3, 0.0))
        return np.where(q < 1, self.sigma * np.clip(1 - q, 0, None) ** 4 * (1 + 4 * q), 0.0)

    def F_np(self, r):
        """F(r) = (dW/dr) / r, as ``F``."""
        import numpy as np

        q = np.asarray(r, dtype=np.float64) / self.H
        H2 = self.H * self.H
        if self.kind == "cubic":
            return np.where(q <= 0.5, self.grad_sigma * (3 * q - 2) / H2,
                            np.where(q < 1, -self.grad_sigma * np.clip(1 - q, 0, None) ** 2
                                     / (H2 * np.maximum(q, 1e-300)), 0.0))
        return np.where(q < 1, -self.grad_sigma * np.clip(1 - q, 0, None) ** 3 / H2, 0.0)
