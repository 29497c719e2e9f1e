"""Melt falling through a vertical bore under its weight, ends open: Poiseuille flow.

Between the ends the pressure is uniform and gravity drives the melt against the no-slip
wall, so that far from the ends the axial velocity is Hagen-Poiseuille's

    u_z(r) = -g (R^2 - r^2) / (4 nu)

(e.g. Batchelor 1967, Sec. 4.2; a body force stands in for the pressure gradient -dp/dz = rho g).
The bore is the nozzle's: radius 0.2 mm, melt at 1000 Pa s. The wall is the lattice outside the
melt's cylinder, so the melt's radius is taken from its cross-section, R = sqrt(N dx^2 / pi)
with N the particles of one layer. The case is quasi-static: one coupled solve, the profile read
over the middle third of the length.
"""

from dataclasses import asdict, dataclass

import numpy as np

from taichi_mex.core.state import FLUID, NOZZLE
from taichi_mex.options import Positive, Range, opt
from taichi_mex.scenes.base import (ParticleBlock, ScenePlan, bore, coupled_pla_defaults,
                                    require_coupled_solve)
from taichi_mex.scenes.registry import SceneEntry, register


class BoreFlowScene:
    name = "bore-flow"

    def __init__(self, radius_mm: float = 0.2, length_radii: float = 8.0):
        self.options = BoreFlowOptions(radius_mm, length_radii)
        self.R = radius_mm * 1e-3
        self.L = length_radii * self.R

    def plan(self, run, material) -> ScenePlan:
        require_coupled_solve(run, "bore flow")
        dx = run.spacing_m
        layers = run.wall_layers()
        b = bore(self.R, self.L, dx, layers)
        melt, wall, radius, outer = b.melt, b.wall, b.radius_m, b.outer_m
        pad = (layers + 3) * dx
        g = run.gravity_m_s2
        nu = material.viscosity_pa_s / material.density_kg_m3
        return ScenePlan(
            name=self.name,
            domain_lo_m=np.array([-outer - pad, -outer - pad, -pad]),
            domain_hi_m=np.array([outer + pad, outer + pad, self.L + pad]),
            t_start_s=0.0, t_end_s=0.0,
            blocks=[ParticleBlock(melt, FLUID), ParticleBlock(wall, NOZZLE)],
            section_point_m=np.array([0.0, 0.0, 0.5 * self.L]),
            section_direction=np.array([0.0, 1.0, 0.0]),
            speed_scale_m_s=max(g * radius**2 / (4 * nu), 1e-9),
            info={"radius_m": radius, "length_m": self.L},
        )

    def analyse(self, sim) -> dict:
        """One coupled solve; the axial velocity of the middle third against Poiseuille's."""
        res = sim.solver.quasi_static()
        nu = sim.material.viscosity_pa_s / sim.material.density_kg_m3
        dx = sim.run_opts.spacing_m
        x = sim.state.numpy("position", FLUID)
        v = sim.state.numpy("velocity", FLUID)
        R = sim.plan.info["radius_m"]
        g = sim.run_opts.gravity_m_s2
        u_max = g * R**2 / (4 * nu)
        middle = np.abs(x[:, 2] - 0.5 * self.L) < self.L / 6
        r = np.hypot(x[middle, 0], x[middle, 1])
        u = -v[middle, 2]
        # the profile: ring averages (one ring per lattice radius) of the melt clear of the
        # wall's staircase, where the lattice's corners stand outside the circle of radius R
        ring = np.round(r / dx, 3)
        rings = np.unique(ring[r <= R - 0.5 * dx])
        profile = [(float(q * dx), float(np.mean(u[ring == q]))) for q in rings]
        err = np.array([(ub - g * (R**2 - rq**2) / (4 * nu)) / u_max for rq, ub in profile])
        return {"profile_error_max": float(np.max(np.abs(err))),
                "profile_error_rms": float(np.sqrt(np.mean(err**2))),
                "centre_ratio": profile[0][1] / (g * (R**2 - profile[0][0]**2) / (4 * nu)),
                "profile_r_m_u_m_s": profile, "poiseuille_u_max_m_s": u_max,
                "radius_m": R, **res.figures()}


@dataclass
class BoreFlowOptions:
    radius_mm: float = opt(0.2, help="bore radius (mm)", check=Positive(), flag="--radius-mm")
    length_radii: float = opt(8.0, help="length of the melt column in bore radii (-)",
                              check=Range(2.0, 100.0))


def _defaults(_options) -> dict:
    return coupled_pla_defaults(0.025)


register(SceneEntry("bore-flow", "melt falling through the nozzle bore (Poiseuille)",
                    BoreFlowOptions, lambda o: BoreFlowScene(**asdict(o)), _defaults))
