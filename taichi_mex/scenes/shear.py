"""Stokes' first problem: a plate under a resting viscous layer starts sliding at speed U.

The plate is a conveyor belt (its particles carry the velocity U but stay in place), so the
wall is infinite in effect. Far from the block's free edges the flow is one-dimensional:

    u(z, t) = U erfc(z / (2 sqrt(nu t)))        (z above the plate, nu = eta / rho)

valid while the layer is thick compared with the penetration depth 2 sqrt(nu t).
"""

import math
from dataclasses import asdict, dataclass

import numpy as np

from taichi_mex.core.state import FLUID, PLATE
from taichi_mex.options import Positive, opt
from taichi_mex.scenes.registry import SceneEntry, register
from taichi_mex.scenes.base import ParticleBlock, ScenePlan, lattice_block


def erfc_profile(z_m, t_s: float, nu_m2_s: float, speed_m_s: float):
    return speed_m_s * np.array([math.erfc(z / (2.0 * math.sqrt(nu_m2_s * t_s))) for z in np.atleast_1d(z_m)])


class ShearStartScene:
    name = "shear"

    def __init__(self, length_mm: float = 6.0, height_mm: float = 3.0, plate_speed_m_s: float = 0.01,
                 until_s: float = 0.01):
        self.options = ShearOptions(length_mm, height_mm, plate_speed_m_s, until_s)
        self.length_m = length_mm * 1e-3
        self.height_m = height_mm * 1e-3
        self.U = float(plate_speed_m_s)
        self.until_s = float(until_s)

    def plan(self, run, material) -> ScenePlan:
        dx = run.spacing_m
        lo = np.zeros(3)
        hi = np.array([self.length_m, self.length_m, self.height_m])
        fluid = lattice_block(lo, hi, dx)
        layers = run.wall_layers()
        pad = 4 * dx
        plate = lattice_block([-pad, -pad, -layers * dx], [self.length_m + pad, self.length_m + pad, 0.0], dx)
        margin = (layers + 3) * dx
        return ScenePlan(
            name=self.name,
            domain_lo_m=lo - margin - pad,
            domain_hi_m=hi + margin + pad,
            t_start_s=0.0, t_end_s=self.until_s,
            blocks=[ParticleBlock(fluid, FLUID),
                    ParticleBlock(plate, PLATE, velocity_m_s=np.array([self.U, 0.0, 0.0]))],
            section_point_m=0.5 * (lo + hi), section_direction=np.array([0.0, 1.0, 0.0]),
            # 40 steps at least: implicit Euler's error in the start-up transient stays small
            speed_scale_m_s=self.U, max_dt_s=self.until_s / 40,
        )

    def analyse(self, sim) -> dict:
        """u_x(z) in the central column against the erfc solution (errors relative to U)."""
        x = sim.state.numpy("position", FLUID)
        v = sim.state.numpy("velocity", FLUID)
        dx = sim.run_opts.spacing_m
        c = 0.5 * self.length_m
        core = (np.abs(x[:, 0] - c) < 0.2 * self.length_m) & (np.abs(x[:, 1] - c) < 0.2 * self.length_m)
        nu = sim.material.viscosity_pa_s * sim.creeping["viscosity_scale"] / sim.material.density_kg_m3
        t = sim.time_s - sim.plan.t_start_s
        depth = 2.0 * math.sqrt(nu * t)
        zs, errs, sim_u, ref_u = [], [], [], []
        for k in range(int(self.height_m / dx)):
            z0 = k * dx
            sel = core & (x[:, 2] >= z0) & (x[:, 2] < z0 + dx)
            if sel.sum() < 3 or z0 > 0.6 * self.height_m:
                continue
            z = float(x[sel, 2].mean())
            u = float(v[sel, 0].mean())
            ref = float(erfc_profile(z, t, nu, self.U)[0])
            zs.append(z)
            sim_u.append(u)
            ref_u.append(ref)
            errs.append(abs(u - ref) / self.U)
        return {"shear_profile_z_m": zs, "shear_profile_u_m_s": sim_u, "shear_profile_ref_m_s": ref_u,
                "shear_error_max_rel_U": float(max(errs)), "shear_error_mean_rel_U": float(np.mean(errs)),
                "penetration_depth_m": depth}


@dataclass
class ShearOptions:
    length_mm: float = opt(6.0, help="block length and width (mm)", check=Positive(),
                           flag="--length-mm")
    height_mm: float = opt(3.0, help="layer thickness (mm)", check=Positive(), flag="--height-mm")
    plate_speed_m_s: float = opt(0.01, help="plate speed U (m/s)", check=Positive(),
                                 flag="--plate-speed", names=("plate_speed",))
    until_s: float = opt(0.01, help="simulated time (s)", check=Positive(), flag="--until",
                         names=("until",))


def _defaults(_options) -> dict:
    # Stokes' first problem is inertial (nu dt / dx^2 ~ 1): the split solve
    return {"run": {"scheme": "dfsph", "spacing_mm": 0.2, "gravity_m_s2": 0.0,
                    "dfsph": {"creeping_solve": "split"}},
            "material": {"name": "shear fluid", "density_kg_m3": 1000.0, "viscosity_pa_s": 0.1,
                         "viscosity_model": "newtonian"}}


register(SceneEntry("shear", "Stokes' first problem: a plate starts sliding under a viscous layer",
                    ShearOptions, lambda o: ShearStartScene(**asdict(o)), _defaults))
