"""Morris, Fox & Zhu's viscous term: "Modeling low Reynolds number incompressible flows using
SPH", J. Comput. Phys. 136, 1997, Eq. 8:

    (1/rho grad . mu grad u)_i = sum_j m_j (mu_i + mu_j) / (rho_i rho_j)
                                  (x_ij . grad W_ij) / (|x_ij|^2 + 0.01 H^2) (u_i - u_j)

the Laplacian of the whole velocity difference, where Weiler et al.'s (2018) operator takes
the difference's projection on the link, ((u_i - u_j) . x_ij) x_ij. For a divergence-free
field with uniform mu both stand for mu lap u. They differ in what a pair resists: Weiler's
link is stiff along itself only, so a particle whose few links lie nearly in one plane is held
across that plane by its inertia alone (benchy's window, the particle flung at the tip's rim:
smallest eigenvalue of its momentum block 3.98 against the melt's median 1.1e5,
validation/windows); Morris's link is stiff in every direction, so each row's diagonal block
is a multiple of the identity no smaller than its largest link's share. The price: a pair's
force is not along the pair, so a rigid rotation of a particle with one-sided neighbours
dissipates (angular momentum is not conserved, Morris et al. say so), where Weiler's does not.

As with Weiler's constant, the continuum's 2 (the mean of mu_i + mu_j) is calibrated on the
lattice so that a quadratic shear profile diffuses at the set viscosity (cubic spline at
H = 2 dx: the lattice sum is 0.496, 0.99 of the continuum's 1/2, where Weiler's reaches 0.70
of its own). The coupled solve
takes a share of it in each pair term, the rest Weiler's (0.1 unless given: physics/stokes.py,
"Operators", has why and what each share measured).
"""

import numpy as np

from taichi_mex.physics.viscosity_weiler2018 import lattice_links


def lattice_laplacian_factor(kernel, spacing_m: float, volume_m3: float) -> float:
    """What sum_j V (u_i - u_j) F r^2 / (r^2 + 0.01 H^2) gives for u = z^2/2 on the cubic
    lattice, F = (dW/dr) / r; the continuum's value is 1/2."""
    _, d, F, u_diff = lattice_links(kernel, spacing_m)
    return float(np.sum(volume_m3 * u_diff * F * d**2 / (d**2 + 0.01 * kernel.H**2)))
