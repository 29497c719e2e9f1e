"""A rigid lid sliding at speed V over a melt film of gap h on the plate, optionally with a
pressure gradient G = -dp/dx along the slide: plane Couette-Poiseuille flow,

    u(z) = V z / h + G z (h - z) / (2 mu)

(e.g. Batchelor, An Introduction to Fluid Dynamics, 1967, Sec. 4.2; Bird, Stewart & Lightfoot,
Transport Phenomena, Ex. 2.3). This is the melt under a print's nozzle face: the plate drags it
one way, the face holds it, and the pressure from the bore pushes it out behind. It checks the
no-slip moving walls (plate and nozzle) on their own, without the bead's free surfaces: the
linear part tests the walls' ghost velocities, the parabola the viscous operator's curvature
next to a wall (where the squeeze film loses force), and ``lid_lift_spacings`` a gap of a
fraction of a spacing between the melt's top layer and the lid's particles, as a print's melt
leaves under the trailing face. G is given as the body force G / rho on the melt (a uniform
force and a pressure gradient drive the same flow between walls; the free rims keep the
pressure at zero). The case is quasi-static: one coupled solve at the initial geometry, the
profile read in the film's middle, away from its rims.
"""

import math
from dataclasses import asdict, dataclass

import numpy as np

from taichi_mex.core.state import FLUID
from taichi_mex.errors import UserInputError
from taichi_mex.options import Positive, Range, opt
from taichi_mex.scenes.base import ScenePlan, coupled_pla_defaults, disc_film, require_coupled_solve
from taichi_mex.scenes.registry import SceneEntry, register

#: the film's middle, where the rims (a gap or more away) leave the profile alone: r < this R
MIDDLE = 0.3


def couette_poiseuille(z_m, gap_m: float, speed_m_s: float, gradient_pa_m: float,
                       viscosity_pa_s: float):
    """u(z) between a plate at rest (z = 0) and a lid at V (z = h), -dp/dx = G (m/s)."""
    z = np.asarray(z_m, dtype=np.float64)
    return speed_m_s * z / gap_m + gradient_pa_m * z * (gap_m - z) / (2.0 * viscosity_pa_s)


class CouetteScene:
    name = "couette"

    def __init__(self, radius_mm: float = 1.0, gap_mm: float = 0.2, speed_mm_s: float = 60.0,
                 gradient_pa_mm: float = 0.0, lid_lift_spacings: float = 0.0):
        self.options = CouetteOptions(radius_mm, gap_mm, speed_mm_s, gradient_pa_mm,
                                      lid_lift_spacings)
        self.R = radius_mm * 1e-3
        self.h = gap_mm * 1e-3
        self.V = speed_mm_s * 1e-3
        self.G = gradient_pa_mm * 1e3  # Pa/m
        self.lift = lid_lift_spacings

    def plan(self, run, material) -> ScenePlan:
        require_coupled_solve(run, "Couette film")
        if self.V == 0.0 and self.G == 0.0:
            raise UserInputError("Nothing drives the Couette film: give the lid a speed "
                                 "(--speed-mm-s) or the film a pressure gradient "
                                 "(--gradient-pa-mm).")
        dx = run.spacing_m
        f = disc_film(self.R, self.h, run, "Couette film", lift_m=self.lift * dx)
        if self.R < 2.0 * self.h / (1.0 - MIDDLE):
            raise UserInputError(f"The lid's radius {self.R * 1e3:g} mm leaves no middle two gaps "
                                 f"clear of the film's rims at gap {self.h * 1e3:g} mm; use "
                                 f"--radius-mm {math.ceil(2e4 * self.h / (1.0 - MIDDLE)) / 10:g} "
                                 "or more.")
        gap, reach, pad = f.gap_m, f.reach_m, f.pad_m
        u_p = self.G * gap * gap / (8.0 * material.viscosity_pa_s)
        return ScenePlan(
            name=self.name,
            domain_lo_m=np.array([-reach - pad, -reach - pad, -pad]),
            domain_hi_m=np.array([reach + pad, reach + pad, gap + (self.lift + 1) * dx + pad]),
            t_start_s=0.0, t_end_s=0.0,
            blocks=f.blocks([self.V, 0.0, 0.0]),
            section_point_m=np.zeros(3), section_direction=np.array([1.0, 0.0, 0.0]),
            speed_scale_m_s=max(self.V + abs(u_p), 1e-9),
            drive=((self.G / material.density_kg_m3, 0.0, 0.0), -math.inf) if self.G != 0.0 else None,
            info={"gap_m": gap, "radius_m": self.R, "speed_m_s": self.V, "gradient_pa_m": self.G,
                  "lid_lift_m": self.lift * dx, "poiseuille_u_max_m_s": u_p},
        )

    def analyse(self, sim) -> dict:
        """One coupled solve; the film's middle, layer by layer, against u(z)."""
        res = sim.solver.quasi_static()
        mu = sim.material.viscosity_pa_s
        info = sim.plan.info
        gap, V, G = info["gap_m"], info["speed_m_s"], info["gradient_pa_m"]
        x = sim.state.numpy("position", FLUID)
        v = sim.state.numpy("velocity", FLUID)
        middle = np.hypot(x[:, 0], x[:, 1]) < MIDDLE * info["radius_m"]
        dx = sim.run_opts.spacing_m
        layer = np.round(x[middle, 2] / dx - 0.5).astype(int)
        u = v[middle, 0]
        z = np.array([(k + 0.5) * dx for k in np.unique(layer)])
        measured = np.array([u[layer == k].mean() for k in np.unique(layer)])
        exact = couette_poiseuille(z, gap, V, G, mu)
        scale = V + abs(info["poiseuille_u_max_m_s"])
        out = {"profile_z_m_u_m_s_exact_m_s": [(float(a), float(b), float(c))
                                               for a, b, c in zip(z, measured, exact)],
               "profile_error_max": float(np.max(np.abs(measured - exact)) / scale),
               "cross_flow_max": float(np.max(np.abs(v[middle, 1:])) / scale),
               **res.figures(), **info, "viscosity_pa_s": mu}
        # where the melt's profile meets the walls' speeds: a quadratic through the layers
        # (exact for u(z)), its roots next to the plate (u = 0) and the lid (u = V); the
        # distance beyond each wall's surface is the wall's slip length
        c = np.polyfit(z, measured, min(2, len(z) - 1))
        out["slip_plate_m"] = -_nearest_root(c, 0.0, 0.0)
        lid = gap + info["lid_lift_m"]  # the lid's surface: half a spacing below its particles
        out["slip_lid_m"] = _nearest_root(c, V, lid) - lid if V != 0.0 else float("nan")
        if G != 0.0:
            # the parabola's share: the measured profile less the lid's line, against G's
            shape = z * (gap - z) / (2.0 * mu)
            out["poiseuille_ratio"] = float(np.dot(measured - V * z / gap, shape)
                                            / (G * np.dot(shape, shape)))
        return out


def _nearest_root(coef, value: float, near: float) -> float:
    """The real z nearest ``near`` where the polynomial ``coef`` equals ``value``."""
    c = np.array(coef, dtype=np.float64)
    c[-1] -= value
    roots = np.roots(c)
    roots = roots[np.abs(roots.imag) < 1e-9 * max(1.0, float(np.abs(roots).max(initial=0.0)))].real
    return float(roots[np.argmin(np.abs(roots - near))]) if len(roots) else float("nan")


@dataclass
class CouetteOptions:
    radius_mm: float = opt(1.0, help="lid and film radius R (mm)", check=Positive(),
                           flag="--radius-mm")
    gap_mm: float = opt(0.2, help="film gap h between plate and lid (mm); a whole number of "
                        "spacings", check=Positive(), flag="--gap-mm")
    speed_mm_s: float = opt(60.0, help="lid speed V along +x (mm/s)", check=Range(0.0, 1e4),
                            flag="--speed-mm-s")
    gradient_pa_mm: float = opt(0.0, help="pressure gradient -dp/dx driving the film along +x "
                                "(Pa/mm), applied as the body force G / rho",
                                check=Range(-1e9, 1e9), flag="--gradient-pa-mm")
    lid_lift_spacings: float = opt(0.0, help="lift of the lid's particles off the melt's top "
                                   "layer, in spacings (-): a gap as under a print's trailing "
                                   "face", check=Range(0.0, 0.9), flag="--lid-lift-spacings")


def _defaults(_options) -> dict:
    return coupled_pla_defaults(0.05, gravity_m_s2=0.0)


register(SceneEntry("couette", "a lid sliding over a melt film (Couette-Poiseuille)",
                    CouetteOptions, lambda o: CouetteScene(**asdict(o)), _defaults))
