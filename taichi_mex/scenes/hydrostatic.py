"""A column of fluid at rest in a tank: pressure must settle to rho g (H - z)."""

import numpy as np

from ..state import FLUID, PLATE
from .base import ScenePlan, box_walls, lattice_block


class HydrostaticScene:
    name = "hydrostatic"

    def __init__(self, width_mm: float = 8.0, height_mm: float = 16.0, until_s: float = 0.3):
        self.width_m = width_mm * 1e-3
        self.height_m = height_mm * 1e-3
        self.until_s = until_s

    def plan(self, run, material) -> ScenePlan:
        dx = run.spacing_m
        lo = np.zeros(3)
        hi = np.array([self.width_m, self.width_m, self.height_m])
        fluid = lattice_block(lo, hi, dx)
        walls = box_walls(lo, hi + np.array([0, 0, 2 * dx]), dx, run.plate_layers, open_top=True)
        pad = (run.plate_layers + 3) * dx
        from .base import ParticleBlock

        return ScenePlan(
            name=self.name,
            domain_lo_m=lo - pad,
            domain_hi_m=hi + np.array([pad, pad, pad + 0.5 * self.height_m]),
            t_start_s=0.0,
            t_end_s=self.until_s,
            blocks=[ParticleBlock(fluid, FLUID), ParticleBlock(walls, PLATE)],
            section_point_m=0.5 * (lo + hi),
            section_direction=np.array([0.0, 1.0, 0.0]),
            notes={"fluid_height_m": float(fluid[:, 2].max() + 0.5 * dx),
                   "speed_scale_m_s": float(np.sqrt(2 * run.gravity_m_s2 * self.height_m))},
        )

    def analyse(self, sim) -> dict:
        """Pressure against rho g depth for the fluid, in bins of height."""
        x = sim.state.numpy("position", FLUID)
        p = sim.state.numpy("pressure", FLUID)
        rho0 = sim.material.density_kg_m3
        g = sim.run_opts.gravity_m_s2
        top = float(x[:, 2].max() + 0.5 * sim.run_opts.spacing_m)
        # exclude the wall-adjacent columns, where the kernel is truncated
        dx = sim.run_opts.spacing_m
        core = (np.min(np.stack([x[:, 0], self.width_m - x[:, 0], x[:, 1], self.width_m - x[:, 1]]), axis=0) > 2 * dx)
        depth = top - x[core, 2]
        expected = rho0 * g * depth
        deep = depth > 0.25 * (top - 0.0)
        rel = np.abs(p[core][deep] - expected[deep]) / (rho0 * g * top)
        return {
            "surface_height_m": top,
            "pressure_error_rel_max": float(rel.max()),
            "pressure_error_rel_mean": float(rel.mean()),
            "bottom_pressure_pa": float(np.median(p[core][depth > 0.9 * top])) if np.any(depth > 0.9 * top) else float("nan"),
            "min_fluid_z_m": float(x[:, 2].min()),
        }
