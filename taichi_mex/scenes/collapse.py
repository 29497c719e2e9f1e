"""A cylinder of isothermal Newtonian fluid released on a no-slip plate: a viscous gravity
current. Reference: Huppert (J. Fluid Mech. 121, 1982), the late-time similarity solution for
a fixed volume V spreading axisymmetrically,

    r_N(t) = eta_N (g V^3 / (3 nu))^(1/8) t^(1/8),   eta_N = (2^10 / (3^4 pi^3))^(1/8) = 0.8939,

valid once the current is thin (r >> h) and creeping; a finite initial shape reaches it with a
virtual time origin t0 (r ~ (t - t0)^(1/8)), so we compare the late-time radius and growth.
"""

import math
from dataclasses import asdict, dataclass

import numpy as np

from taichi_mex.core.state import FLUID, PLATE
from taichi_mex.options import Positive, Range, opt
from taichi_mex.scenes.registry import SceneEntry, register
from taichi_mex.scenes.base import ParticleBlock, ScenePlan, lattice_block

HUPPERT_ETA_N = (2**10 / (3**4 * math.pi**3)) ** 0.125


def huppert_radius(t_s, volume_m3: float, nu_m2_s: float, g_m_s2: float = 9.81):
    return HUPPERT_ETA_N * (g_m_s2 * volume_m3**3 / (3.0 * nu_m2_s)) ** 0.125 * np.asarray(t_s) ** 0.125


class CollapseScene:
    name = "collapse"

    def __init__(self, radius_mm: float = 3.0, height_mm: float = 10.0, until_s: float = 5.0,
                 samples: int = 40):
        self.options = CollapseOptions(radius_mm, height_mm, until_s, samples)
        self.R = radius_mm * 1e-3
        self.Hc = height_mm * 1e-3
        self.until_s = float(until_s)
        # log-spaced sample times (the 1/8 power law is best seen on a log axis) and evenly
        # spaced ones, so that short runs still give `samples` rows
        self.sample_times = np.unique(np.concatenate([
            np.geomspace(max(self.until_s * 1e-3, 1e-4), self.until_s, samples),
            np.linspace(self.until_s / samples, self.until_s, samples)]))
        self.front: list[tuple[float, float]] = []

    def plan(self, run, material) -> ScenePlan:
        dx = run.spacing_m
        box = lattice_block([-self.R, -self.R, 0.0], [self.R, self.R, self.Hc], dx)
        fluid = box[np.hypot(box[:, 0], box[:, 1]) < self.R]
        volume = len(fluid) * dx**3
        nu = material.viscosity_pa_s / material.density_kg_m3
        r_end = float(huppert_radius(self.until_s, volume, nu, run.gravity_m_s2))
        reach = max(1.5 * r_end, 2.0 * self.R) + 4 * dx
        layers = run.wall_layers()
        plate = lattice_block([-reach, -reach, -layers * dx], [reach, reach, 0.0], dx)
        pad = (layers + 3) * dx
        self.front = []
        self._next = 0
        return ScenePlan(
            name=self.name,
            domain_lo_m=np.array([-reach - pad, -reach - pad, -pad]),
            domain_hi_m=np.array([reach + pad, reach + pad, self.Hc + pad]),
            t_start_s=0.0, t_end_s=self.until_s,
            blocks=[ParticleBlock(fluid, FLUID),
                    ParticleBlock(plate, PLATE, wall_depth_m=-plate[:, 2], wall_normal=(0, 0, 1))],
            section_point_m=np.zeros(3), section_direction=np.array([0.0, 1.0, 0.0]),
            speed_scale_m_s=math.sqrt(run.gravity_m_s2 * self.Hc),
            # no cap besides the run's length: the melt's own motion sets the step (the CFL
            # limit, a fifth of a spacing a step; Monaghan's force criterion before the first),
            # and in a creeping slump that motion decays as t^(-7/8). A cap of a fifth of the
            # slump time eta / (rho g H), kept until 2026-12-05, took 237 steps where the CFL
            # limit alone takes 54 at 0.5 mm, 10 Pa s, 12 s, with Huppert's coefficient 1.016
            # against 1.018 (validation/collapse)
            max_dt_s=self.until_s, info={"volume_m3": volume},
            # the front moves out to Huppert's radius and the top falls by about the column's
            # height: no melt travels much further than the larger of the two
            travel_m=max(r_end - self.R, self.Hc),
        )

    def front_radius(self, sim) -> float:
        """Radius of the spreading front at the plate: the outermost particles of the bottom
        layer (95th percentile of the outer tenth, so a lone particle cannot set it)."""
        x = sim.state.numpy("position", FLUID)
        dx = sim.run_opts.spacing_m
        bottom = x[x[:, 2] < 1.5 * dx]
        if len(bottom) == 0:
            return 0.0
        r = np.hypot(bottom[:, 0], bottom[:, 1])
        outer = np.sort(r)[-max(len(r) // 10, 1):]
        return float(np.percentile(outer, 95) + 0.5 * dx)

    def monitor(self, sim, t: float) -> None:
        crossed = False
        while self._next < len(self.sample_times) and t >= self.sample_times[self._next] - 1e-12:
            self._next += 1
            crossed = True
        if crossed:
            self.front.append((t, self.front_radius(sim)))

    def analyse(self, sim) -> dict:
        nu = sim.material.viscosity_pa_s / sim.material.density_kg_m3
        V = sim.plan.info["volume_m3"]
        g = sim.run_opts.gravity_m_s2
        if not self.front or self.front[-1][0] < sim.time_s - 1e-9:
            self.front.append((sim.time_s, self.front_radius(sim)))
        # a run stopped at its start has only t = 0, where Huppert's radius is 0
        front = [f for f in self.front if f[0] > 0.0]
        if not front:
            nan = float("nan")
            return {"front_t_s": [], "front_r_m": [], "huppert_r_m": [], "front_ratio_late": nan,
                    "front_coefficient_ratio": nan, "front_virtual_origin_s": nan,
                    "front_exponent_late": nan, "volume_m3": V, "nu_m2_s": nu}
        t = np.array([f[0] for f in front])
        r = np.array([f[1] for f in front])
        ref = huppert_radius(t, V, nu, g)
        late = t >= 0.5 * t[-1]
        # growth exponent over the last decade of samples
        tail = t >= t[-1] / 10
        exponent = float(np.polyfit(np.log(t[tail]), np.log(r[tail]), 1)[0]) if tail.sum() > 2 else float("nan")
        # Huppert with a virtual time origin: r^8 = K (t - t0) late in the run; K^(1/8)
        # against eta_N (g V^3 / (3 nu))^(1/8) does not depend on how the cylinder started
        coeff_ratio = t0 = float("nan")
        if late.sum() > 2:
            slope, icpt = np.polyfit(t[late], r[late] ** 8, 1)
            if slope > 0:
                coeff_ratio = float(slope ** 0.125 / float(huppert_radius(1.0, V, nu, g)))
                t0 = float(-icpt / slope)
        return {"front_t_s": t.tolist(), "front_r_m": r.tolist(), "huppert_r_m": ref.tolist(),
                "front_ratio_late": float(np.mean(r[late] / ref[late])),
                "front_coefficient_ratio": coeff_ratio, "front_virtual_origin_s": t0,
                "front_exponent_late": exponent, "volume_m3": V, "nu_m2_s": nu}

    def write_outputs(self, sim, out_dir) -> None:
        s = self.analyse(sim)
        lines = ["t_s,r_front_m"] + [f"{t:.6g},{r:.6g}" for t, r in zip(s["front_t_s"], s["front_r_m"])]
        (out_dir / "front.csv").write_text("\n".join(lines) + "\n")
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 4))
        ax.loglog(s["front_t_s"], np.array(s["front_r_m"]) * 1e3, "o", ms=3, label="SPH front")
        ax.loglog(s["front_t_s"], np.array(s["huppert_r_m"]) * 1e3, "-", label="Huppert (1982)")
        ax.set_xlabel("t [s]")
        ax.set_ylabel("front radius [mm]")
        ax.legend()
        ax.set_title(f"viscous collapse, nu = {s['nu_m2_s']:.3g} m^2/s")
        fig.tight_layout()
        fig.savefig(out_dir / "front.png", dpi=120)
        plt.close(fig)


@dataclass
class CollapseOptions:
    radius_mm: float = opt(4.0, help="initial cylinder radius (mm)", check=Positive(),
                           flag="--radius-mm")
    height_mm: float = opt(4.0, help="initial cylinder height (mm)", check=Positive(),
                           flag="--height-mm")
    until_s: float = opt(2.0, help="simulated time (s)", check=Positive(), flag="--until",
                         names=("until",))
    samples: int = opt(40, help="front samples, log-spaced and evenly spaced in time",
                       check=Range(3, 10000, integer=True))


def _defaults(_options) -> dict:
    return {"run": {"scheme": "dfsph", "spacing_mm": 0.5},
            "material": {"name": "collapse fluid", "density_kg_m3": 1000.0, "viscosity_pa_s": 10.0,
                         "viscosity_model": "newtonian"}}


register(SceneEntry("collapse", "a viscous cylinder slumping on a no-slip plate (Huppert 1982)",
                    CollapseOptions, lambda o: CollapseScene(**asdict(o)), _defaults))
