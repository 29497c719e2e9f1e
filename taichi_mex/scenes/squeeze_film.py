"""A rigid disc of radius R pressed at speed V towards a no-slip plate through a melt film of
gap h (h << R): Stefan's squeeze film. Lubrication theory gives the film's pressure
p(r) = 3 mu V (R^2 - r^2) / h^3 and the force on the disc

    F = 3 pi mu V R^4 / (2 h^3)

(Stefan 1874; e.g. Batchelor, An Introduction to Fluid Dynamics, 1967, Sec. 4.8; Bird,
Armstrong & Hassager, Dynamics of Polymeric Liquids vol. 1, 1987, Example 1.2-5), and in the
Stokes limit the velocities do not depend on mu. This is the nozzle face pressing melt onto the
bed, without the bore: it tests the coupled viscous-pressure solve and the no-slip walls where
a print's bead is shaped. The case is quasi-static: one coupled solve at the initial geometry,
the force summed on the disc's particles.
"""

import math
from dataclasses import asdict, dataclass

import numpy as np

from taichi_mex.core.state import FLUID, NOZZLE
from taichi_mex.options import Positive, opt
from taichi_mex.scenes.base import ScenePlan, coupled_pla_defaults, disc_film, require_coupled_solve
from taichi_mex.scenes.registry import SceneEntry, register


def stefan_force_n(viscosity_pa_s: float, speed_m_s: float, radius_m: float, gap_m: float) -> float:
    return 3.0 * math.pi * viscosity_pa_s * speed_m_s * radius_m**4 / (2.0 * gap_m**3)


class SqueezeFilmScene:
    name = "squeeze-film"

    def __init__(self, radius_mm: float = 1.0, gap_mm: float = 0.3, speed_mm_s: float = 1.0):
        self.options = SqueezeFilmOptions(radius_mm, gap_mm, speed_mm_s)
        self.R = radius_mm * 1e-3
        self.h = gap_mm * 1e-3
        self.V = speed_mm_s * 1e-3

    def plan(self, run, material) -> ScenePlan:
        require_coupled_solve(run, "squeeze film")
        f = disc_film(self.R, self.h, run, "squeeze film")
        reach, pad = f.reach_m, f.pad_m
        return ScenePlan(
            name=self.name,
            domain_lo_m=np.array([-reach - pad, -reach - pad, -pad]),
            domain_hi_m=np.array([reach + pad, reach + pad, self.h + pad]),
            t_start_s=0.0, t_end_s=0.0,
            blocks=f.blocks([0.0, 0.0, -self.V]),
            section_point_m=np.zeros(3), section_direction=np.array([0.0, 1.0, 0.0]),
            speed_scale_m_s=self.V, info={"gap_m": f.gap_m, "radius_m": self.R, "speed_m_s": self.V},
        )

    def analyse(self, sim) -> dict:
        """One coupled solve; the force on the disc against Stefan's law, and the film's
        centre pressure against 3 mu V R^2 / h^3."""
        solver = sim.solver
        mu = sim.material.viscosity_pa_s
        rho = sim.material.density_kg_m3
        res = solver.quasi_static()
        phase = sim.state.numpy("phase")
        force = solver.stokes.wall_force(phase == NOZZLE)
        gap, R = sim.plan.info["gap_m"], sim.plan.info["radius_m"]
        ref = stefan_force_n(mu, self.V, R, gap)
        x = sim.state.numpy("position", FLUID)
        k = solver.dfsph.kappa.to_numpy()[: sim.state.n][phase == FLUID]
        r = np.hypot(x[:, 0], x[:, 1])
        centre = r < 0.15 * R
        p_centre = float(np.median(k[centre])) * rho if centre.any() else float("nan")
        return {"force_n": float(force[2]), "stefan_force_n": ref,
                "force_ratio": float(force[2] / ref),
                "centre_pressure_ratio": p_centre / (3 * mu * self.V * R**2 / gap**3),
                **res.figures(), "gap_m": gap, "radius_m": R, "speed_m_s": self.V, "viscosity_pa_s": mu}


@dataclass
class SqueezeFilmOptions:
    radius_mm: float = opt(1.0, help="disc radius R (mm)", check=Positive(), flag="--radius-mm")
    gap_mm: float = opt(0.3, help="film gap h between disc and plate (mm); a whole number of "
                        "spacings", check=Positive(), flag="--gap-mm")
    speed_mm_s: float = opt(1.0, help="disc speed towards the plate V (mm/s)", check=Positive(),
                            flag="--speed-mm-s")


def _defaults(_options) -> dict:
    return coupled_pla_defaults(0.05, gravity_m_s2=0.0)


register(SceneEntry("squeeze-film", "a disc squeezing a melt film onto the plate (Stefan's law)",
                    SqueezeFilmOptions, lambda o: SqueezeFilmScene(**asdict(o)), _defaults))
