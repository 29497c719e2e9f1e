"""A column of fluid at rest in a tank: pressure must settle to rho g (H - z)."""

from dataclasses import asdict, dataclass

import numpy as np

from taichi_mex.core.state import FLUID, PLATE
from taichi_mex.options import Positive, opt
from taichi_mex.scenes.registry import SceneEntry, register
from taichi_mex.scenes.base import ScenePlan, box_walls, lattice_block


class HydrostaticScene:
    name = "hydrostatic"

    def __init__(self, width_mm: float = 8.0, height_mm: float = 16.0, until_s: float = 0.3):
        self.options = HydrostaticOptions(width_mm, height_mm, until_s)
        self.width_m = width_mm * 1e-3
        self.height_m = height_mm * 1e-3
        self.until_s = until_s

    def plan(self, run, material) -> ScenePlan:
        dx = run.spacing_m
        lo = np.zeros(3)
        hi = np.array([self.width_m, self.width_m, self.height_m])
        fluid = lattice_block(lo, hi, dx)
        walls = box_walls(lo, hi + np.array([0, 0, 2 * dx]), dx, run.wall_layers(), open_top=True)
        pad = (run.wall_layers() + 3) * dx
        from taichi_mex.scenes.base import ParticleBlock

        return ScenePlan(
            name=self.name,
            domain_lo_m=lo - pad,
            domain_hi_m=hi + np.array([pad, pad, pad + 0.5 * self.height_m]),
            t_start_s=0.0,
            t_end_s=self.until_s,
            blocks=[ParticleBlock(fluid, FLUID), ParticleBlock(walls, PLATE)],
            section_point_m=0.5 * (lo + hi),
            section_direction=np.array([0.0, 1.0, 0.0]),
            speed_scale_m_s=float(np.sqrt(2 * run.gravity_m_s2 * self.height_m)),
            info={"fluid_height_m": float(fluid[:, 2].max() + 0.5 * dx)},
        )

    def analyse(self, sim) -> dict:
        """Pressure against rho g depth, averaged over horizontal slabs one spacing thick.

        SPH pressure carries particle-scale noise (an implicit solver's Jacobi iterations
        leave some); the hydrostatic law is a statement about the continuum, i.e. the slab
        mean. Particles within 1.5 spacings of a wall (truncated kernel; the first layer nests
        into the wall lattice's hollows) are left out."""
        x = sim.state.numpy("position", FLUID)
        p = sim.state.numpy("pressure", FLUID).astype(np.float64)
        rho0 = sim.material.density_kg_m3
        g = sim.run_opts.gravity_m_s2
        dx = sim.run_opts.spacing_m
        # the free surface of an incompressible column: its volume over the tank's cross-section
        top = len(x) * dx**3 / self.width_m**2
        core = np.min(np.stack([x[:, 0], self.width_m - x[:, 0], x[:, 1], self.width_m - x[:, 1],
                                x[:, 2]]), axis=0) > 1.5 * dx
        depth = np.maximum(top - x[core, 2], 0.0)
        slab = np.floor(depth / dx).astype(int)
        rel = []
        bottom = bottom_expected = float("nan")
        per_layer = max(int(core.sum() / max(slab.max(), 1)), 1)
        slab_depth, slab_p = [], []
        for k in range(1, int(slab.max()) + 1):  # slab 0 is the free-surface layer
            sel = slab == k
            if sel.sum() < 0.25 * per_layer:
                continue
            mean_p = float(p[core][sel].mean())
            expected = rho0 * g * float(depth[sel].mean())
            rel.append(abs(mean_p - expected) / (rho0 * g * top))
            bottom, bottom_expected = mean_p, expected
            slab_depth.append(float(depth[sel].mean()))
            slab_p.append(mean_p)
        # the slope dp/dz must be rho g, wherever the discrete free surface sits
        slope = float(np.polyfit(slab_depth, slab_p, 1)[0]) if len(slab_p) > 2 else float("nan")
        return {
            "pressure_gradient_rel_error": abs(slope / (rho0 * g) - 1.0),
            "surface_height_m": top,
            "pressure_error_rel_max": float(max(rel)),
            "pressure_error_rel_mean": float(np.mean(rel)),
            "deepest_slab_pressure_pa": bottom,
            "deepest_slab_expected_pa": bottom_expected,
            "min_fluid_z_m": float(x[:, 2].min()),
        }


@dataclass
class HydrostaticOptions:
    width_mm: float = opt(8.0, help="tank width (mm)", check=Positive(), flag="--width-mm")
    height_mm: float = opt(12.0, help="fluid height (mm)", check=Positive(), flag="--height-mm")
    until_s: float = opt(0.3, help="simulated time (s)", check=Positive(), flag="--until",
                         names=("until",))


def _defaults(options) -> dict:
    # EDAC's artificial sound speed: ten times the fastest free-fall speed over the column
    c = 10 * float(np.sqrt(2 * 9.81 * options.height_mm * 1e-3))
    # an inertial column: the split solve (DFSPH)
    return {"run": {"scheme": "dfsph", "spacing_mm": 1.0, "edac": {"sound_speed_m_s": c},
                    "dfsph": {"creeping_solve": "split"}},
            "material": {"name": "water-like", "density_kg_m3": 1000.0, "viscosity_pa_s": 1.0,
                         "viscosity_model": "newtonian"}}


register(SceneEntry("hydrostatic", "a fluid column at rest: pressure against rho g depth",
                    HydrostaticOptions, lambda o: HydrostaticScene(**asdict(o)), _defaults))
