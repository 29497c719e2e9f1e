"""PySPH's 3D dam break (``pysph.examples.dam_break_3d``) with the EDAC scheme: the peer
benchmark's scene (``python -m taichi_mex bench dam-break``, see :mod:`taichi_mex.app.peer`).

The water column of SPHERIC benchmark test 2 (Kleefsman et al., J. Comput. Phys. 206,
2005; 1.228 x 1.0 x 0.55 m) collapses in a 3.22 x 1.0 x 1.0 m open tank towards a
0.16 x 0.4 x 0.161 m box. The particles are those of PySPH's ``DamBreak3DGeometry``
(``pysph/examples/_db_geometry.py``, nboundary_layers = 1): one Cartesian lattice of spacing
dx that starts nboundary_layers spacings outside the tank (the tank spans y in [-W/2, W/2]);

* fluid:     0 < x <= 1.228, -W/2 < y < W/2 (strict), 0 < z <= 0.55
* obstacle:  |x - 2.5| <= 0.08, |y| <= 0.2, 0 < z <= 0.161
* tank:      x <= 0 or x >= 3.22 or |y| >= W/2 or z <= 0 (open top, walls up to z = H + g)

We evaluate these tests on lattice indices (coordinates in units of dx, with a 1e-6 dx
tolerance) instead of on floats, so that lattice points lying on a face count as PySPH
meant them; at dx = 0.02 this gives PySPH's counts exactly: 80,703 fluid, 60,836 tank and
1,512 obstacle particles (143,051). Tank and obstacle are fixed boundary particles (PLATE).

Physics as PySPH's EDACScheme with pb = 0, nu = 0, h = 1.3 dx (Wendland C2 with support
2h = 2.6 dx, PySPH's WendlandQuintic), rho0 = 1000 kg/m^3, c0 = 10 sqrt(2 g 0.55) m/s,
gravity -9.81 m/s^2 in z, pressure and velocity zero at the start.
"""

import math
from dataclasses import dataclass

import numpy as np

from taichi_mex.core.state import FLUID, PLATE
from taichi_mex.options import Positive, opt
from taichi_mex.scenes.registry import SceneEntry, register
from taichi_mex.scenes.base import ParticleBlock, ScenePlan

#: lattice coordinates (units of dx) closer than this to a face count as on it
_TOL = 1e-6


@dataclass(frozen=True)
class DamBreakGeometry:
    """Dimensions of PySPH's DamBreak3DGeometry (m); y is centred on the tank."""

    container_length_m: float = 3.22
    container_width_m: float = 1.0
    container_height_m: float = 1.0
    fluid_length_m: float = 1.228
    fluid_height_m: float = 0.55
    obstacle_center_x_m: float = 2.5
    obstacle_center_y_m: float = 0.0
    obstacle_length_m: float = 0.16
    obstacle_width_m: float = 0.4
    obstacle_height_m: float = 0.161
    boundary_layers: int = 1

    def particles(self, dx_m: float) -> dict[str, np.ndarray]:
        """{'fluid', 'boundary', 'obstacle'}: (n, 3) positions in m, in lattice order."""
        L, W, H = self.container_length_m, self.container_width_m, self.container_height_m
        nbl = self.boundary_layers
        # PySPH's mgrid runs from -g to L + g (+0.1 dx, exclusive); in units of dx
        counts = [int(math.ceil(extent / dx_m + 2 * nbl + 0.1 - _TOL)) for extent in (L, W, H)]
        ix, iy, iz = np.meshgrid(*(np.arange(c, dtype=np.float64) for c in counts), indexing="ij")
        X = ix.ravel() - nbl                       # x / dx
        Y = iy.ravel() - nbl - 0.5 * W / dx_m      # y / dx
        Z = iz.ravel() - nbl                       # z / dx
        half_w = 0.5 * W / dx_m
        fluid = ((X > _TOL) & (X <= self.fluid_length_m / dx_m + _TOL)
                 & (Y > -half_w + _TOL) & (Y < half_w - _TOL)
                 & (Z > _TOL) & (Z <= self.fluid_height_m / dx_m + _TOL))
        ocx, ocy = self.obstacle_center_x_m / dx_m, self.obstacle_center_y_m / dx_m
        obl, obw = 0.5 * self.obstacle_length_m / dx_m, 0.5 * self.obstacle_width_m / dx_m
        obstacle = ((X >= ocx - obl - _TOL) & (X <= ocx + obl + _TOL)
                    & (Y >= ocy - obw - _TOL) & (Y <= ocy + obw + _TOL)
                    & (Z > _TOL) & (Z <= self.obstacle_height_m / dx_m + _TOL))
        tank = ((Y <= -half_w + _TOL) | (Y >= half_w - _TOL) | (X >= L / dx_m - _TOL)
                | (X <= _TOL) | (Z <= _TOL))
        xyz = np.stack([X, Y, Z], axis=1) * dx_m
        return {"fluid": xyz[fluid], "boundary": xyz[tank], "obstacle": xyz[obstacle]}

    def max_speed_m_s(self, g_m_s2: float = 9.81) -> float:
        """Free-fall speed from the column's height, sqrt(2 g H_fluid)."""
        return math.sqrt(2.0 * g_m_s2 * self.fluid_height_m)


class DamBreak3DScene:
    name = "dam-break"

    def __init__(self, until_s: float = 1.0, geometry: DamBreakGeometry | None = None,
                 dx_m: float = 0.02):
        # dx_m: the spacing the scene implies for the run (run_options), kept for config.json
        self.options = DamBreakOptions(dx_m, until_s)
        self.until_s = float(until_s)
        self.geometry = geometry or DamBreakGeometry()
        self.counts: dict[str, int] = {}

    def plan(self, run, material) -> ScenePlan:
        dx = run.spacing_m
        geo = self.geometry
        parts = geo.particles(dx)
        self.counts = {k: len(v) for k, v in parts.items()}
        walls = np.concatenate([parts["boundary"], parts["obstacle"]])
        lo = walls.min(axis=0)
        hi = walls.max(axis=0)
        pad = 3.0 * dx
        # headroom above the open tank: the flood climbs the far wall (the run drops what
        # leaves the domain and reports it as lost)
        top = 0.5 * geo.container_height_m
        return ScenePlan(
            name=self.name,
            domain_lo_m=lo - pad,
            domain_hi_m=hi + np.array([pad, pad, pad + top]),
            t_start_s=0.0,
            t_end_s=self.until_s,
            blocks=[ParticleBlock(parts["fluid"], FLUID), ParticleBlock(walls, PLATE)],
            section_point_m=np.array([0.5 * geo.container_length_m, 0.0, 0.5 * geo.fluid_height_m]),
            section_direction=np.array([1.0, 0.0, 0.0]),
            speed_scale_m_s=geo.max_speed_m_s(run.gravity_m_s2),
            info={"fluid_particles": self.counts["fluid"],
                   "boundary_particles": self.counts["boundary"],
                   "obstacle_particles": self.counts["obstacle"]},
        )

    def analyse(self, sim) -> dict:
        """Surge front: the largest x of the fluid (95th percentile of the leading tenth)."""
        x = sim.state.numpy("position", FLUID)
        if len(x) == 0:
            return {"front_x_m": float("nan")}
        lead = np.sort(x[:, 0])[-max(len(x) // 10, 1):]
        return {"front_x_m": float(np.percentile(lead, 95)),
                "max_fluid_z_m": float(x[:, 2].max())}


def sound_speed_m_s(geometry: DamBreakGeometry | None = None, g_m_s2: float = 9.81) -> float:
    """PySPH's choice, c0 = 10 sqrt(2 g H_fluid) = 32.85 m/s for the 0.55 m column."""
    return 10.0 * (geometry or DamBreakGeometry()).max_speed_m_s(g_m_s2)


#: EDAC time step factor: PySPH's EDAC examples step with a fixed dt = 0.125 h / c0; ours,
#: dt = cfl h / (c0 + |v|max), equals it while the flow is slow against c0
CFL = 0.125
#: PySPH's nu = 0 (inviscid): EDAC then skips the viscous term, as PySPH does (EDAC's own
#: pressure diffusion, nu_edac = h c0 / 16, does not depend on it)
INVISCID_PA_S = 0.0


def run_options(dx_m: float = 0.02) -> dict:
    """RunOptions overrides that make our EDAC the PySPH configuration above."""
    return {"scheme": "edac", "spacing_mm": dx_m * 1e3, "kernel": "wendland_c2",
            "support_factor": 2.6, "gravity_m_s2": 9.81,
            "edac": {"sound_speed_m_s": sound_speed_m_s(), "cfl": CFL, "edac_alpha": 0.5,
                     "clamp_wall_pressure": False}}


def material() -> dict:
    return {"name": "water (inviscid)", "density_kg_m3": 1000.0, "viscosity_pa_s": INVISCID_PA_S,
            "viscosity_model": "newtonian"}


@dataclass
class DamBreakOptions:
    dx_m: float = opt(0.02, help="particle spacing (m), as PySPH's --dx (0.02: 143,051 "
                      "particles); sets the run's spacing", check=Positive(), flag="--dx")
    until_s: float = opt(1.0, help="simulated time (s; PySPH's example runs to 6 s)",
                         check=Positive(), flag="--until", names=("until",))


register(SceneEntry("dam-break", "PySPH's 3D dam break (SPHERIC test 2) with EDAC, 143k particles",
                    DamBreakOptions, lambda o: DamBreak3DScene(o.until_s, dx_m=o.dx_m),
                    lambda o: {"run": run_options(o.dx_m), "material": material()}))
