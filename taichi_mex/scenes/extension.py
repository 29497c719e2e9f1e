"""Uniaxial extension of a melt filament: a cylinder of radius R0 and length L0 whose end
pieces are pulled apart at a constant Hencky strain rate e. In creeping Newtonian flow the
filament stretches uniformly,

    u = e (x, -y / 2, -z / 2),   R(t) = R0 exp(-e t / 2),   p = -mu e,

the pressure being the tension that makes the side traction-free: sigma_rr = -p + 2 mu (-e / 2)
= 0 (Trouton 1906; e.g. Bird, Armstrong & Hassager, Dynamics of Polymeric Liquids vol. 1,
1987, Sec. 3.5; the ideal that filament-stretching rheometers approach, McKinley & Sridhar,
Annu. Rev. Fluid Mech. 34, 2002). It tests what a strand's sides and a stretched neck need and
the other validation cases do not: a free surface whose melt is under tension, incompressible
both ways.

The end pieces carry that same field (their particles are moving walls, scaled about the
filament's centre by exp(e t) along its axis and exp(-e t / 2) across it, exactly), so the
boundary data are the exact solution's and any departure in the middle is the solver's. The
mid radius is R_mid = sqrt(2 <r^2>) over the melt within three spacings of the centre plane
(a filled disc's second moment), reported relative to its value at the start, which removes
the lattice's staircase; the pressure there is compared with -mu e.
"""

import math
from dataclasses import asdict, dataclass

import numpy as np

from taichi_mex.backend import ti
from taichi_mex.core.state import FLUID, NOZZLE
from taichi_mex.options import Positive, Range, opt
from taichi_mex.scenes.base import (ParticleBlock, ScenePlan, coupled_pla_defaults, lattice_block,
                                    require_coupled_solve)
from taichi_mex.scenes.registry import SceneEntry, register


@ti.kernel
def _stretch(x: ti.template(), v: ti.template(), phase: ti.template(), n: ti.i32,
             along: float, across: float, rate: float, cx: float, cy: float, cz: float):
    """Scale the end pieces about the centre (state coordinates) and give them the field."""
    for i in range(n):
        if phase[i] == NOZZLE:
            c = ti.Vector([cx, cy, cz])
            r = x[i] - c
            r = ti.Vector([r[0] * along, r[1] * across, r[2] * across])
            x[i] = c + r
            v[i] = rate * ti.Vector([r[0], -0.5 * r[1], -0.5 * r[2]])


def extension_field(x_m: np.ndarray, rate_1_s: float) -> np.ndarray:
    return rate_1_s * np.stack([x_m[:, 0], -0.5 * x_m[:, 1], -0.5 * x_m[:, 2]], axis=1)


class ExtensionScene:
    name = "extension"

    def __init__(self, radius_mm: float = 0.5, length_mm: float = 4.0, strain_rate: float = 1.0,
                 strain: float = 0.5, samples: int = 10):
        self.options = ExtensionOptions(radius_mm, length_mm, strain_rate, strain, samples)
        self.R0 = radius_mm * 1e-3
        self.L0 = length_mm * 1e-3
        self.rate = float(strain_rate)
        self.t_end = float(strain) / self.rate
        self.sample_times = np.linspace(0.0, self.t_end, int(samples) + 1)[1:]
        self.history: list[tuple[float, float, float]] = []
        self._moved_to = 0.0
        self._next = 0

    def plan(self, run, material) -> ScenePlan:
        require_coupled_solve(run, "uniaxial extension")
        dx = run.spacing_m
        layers = run.wall_layers()
        grip = (layers + 1) * dx
        half = 0.5 * self.L0
        box = lattice_block([-half - grip, -self.R0, -self.R0], [half + grip, self.R0, self.R0], dx)
        box = box[np.hypot(box[:, 1], box[:, 2]) < self.R0]
        melt = box[np.abs(box[:, 0]) < half]
        ends = box[np.abs(box[:, 0]) >= half]
        stretch = math.exp(self.rate * self.t_end)
        reach_x = (half + grip) * stretch + (layers + 3) * dx
        reach_r = self.R0 + (layers + 3) * dx
        self.history = []
        self._moved_to = 0.0
        self._next = 0
        self.dx = dx
        self.half_span = half + grip
        # at rest: no pressure yet
        self.start_section = (self._mid_radius(melt, self._middle(melt)), 0.0)
        return ScenePlan(
            name=self.name,
            domain_lo_m=np.array([-reach_x, -reach_r, -reach_r]),
            domain_hi_m=np.array([reach_x, reach_r, reach_r]),
            t_start_s=0.0, t_end_s=self.t_end,
            blocks=[ParticleBlock(melt, FLUID, velocity_m_s=extension_field(melt, self.rate)),
                    ParticleBlock(ends, NOZZLE, velocity_m_s=extension_field(ends, self.rate))],
            section_point_m=np.zeros(3), section_direction=np.array([1.0, 0.0, 0.0]),
            speed_scale_m_s=self.rate * (half + grip) * stretch,
            # a creeping melt has no step limit of its own: the strain per step is the
            # explicit position update's error (0.01: 0.06 % in R at strain 0.5)
            max_dt_s=0.01 / self.rate,
            info={"radius_m": self.R0, "length_m": self.L0, "strain_rate_1_s": self.rate,
                  "melt_particles": int(len(melt)), "end_particles": int(len(ends))},
        )

    # ------------------------------------------------------------ called by the simulation
    def move_walls(self, sim, t: float) -> None:
        """The end pieces to time t (from where the last call left them)."""
        dt = t - self._moved_to
        if dt == 0.0:
            return
        st = sim.state
        c = -np.asarray(st.origin_m, dtype=np.float64)  # the filament's centre, state coordinates
        _stretch(st.x, st.v, st.phase, st.n, math.exp(self.rate * dt),
                 math.exp(-0.5 * self.rate * dt), self.rate, *(float(v) for v in c))
        self._moved_to = t
        sim.grid.stale = True

    def wall_speed(self) -> float:
        """The end pieces' fastest particle (m/s): their far faces."""
        return self.rate * self.half_span * math.exp(self.rate * self._moved_to)

    def mid_section(self, sim) -> tuple[float, float]:
        """(sqrt(2 <r^2>), mean pressure) of the melt within three spacings of the centre plane."""
        x = sim.state.numpy("position", FLUID)
        mid = self._middle(x)
        if not mid.any():
            return float("nan"), float("nan")
        p = sim.state.numpy("pressure", FLUID)[mid]
        return self._mid_radius(x, mid), float(np.mean(p))

    def _middle(self, x_m: np.ndarray) -> np.ndarray:
        """Melt within three spacings of the centre plane."""
        return np.abs(x_m[:, 0]) < 3.0 * self.dx

    @staticmethod
    def _mid_radius(x_m: np.ndarray, mid: np.ndarray) -> float:
        """sqrt(2 <r^2>): a filled disc's radius from its second moment."""
        return math.sqrt(2.0 * float(np.mean(x_m[mid, 1] ** 2 + x_m[mid, 2] ** 2)))

    def monitor(self, sim, t: float) -> None:
        if not self.history:
            self.history.append((0.0, *self.start_section))
        crossed = False
        while self._next < len(self.sample_times) and t >= self.sample_times[self._next] - 1e-9:
            self._next += 1
            crossed = True
        if crossed:
            self.history.append((t, *self.mid_section(sim)))

    def analyse(self, sim) -> dict:
        mu = sim.material.viscosity_pa_s
        if not self.history:
            self.history.append((0.0, *self.start_section))
        if self.history[-1][0] < sim.time_s - 1e-9:
            self.history.append((sim.time_s, *self.mid_section(sim)))
        t = np.array([h[0] for h in self.history])
        r = np.array([h[1] for h in self.history])
        p = np.array([h[2] for h in self.history])
        ratio = r / r[0]
        ref = np.exp(-0.5 * self.rate * t)
        err = ratio / ref - 1.0
        later = t > 0.0
        nan = float("nan")
        return {"t_s": t.tolist(), "mid_radius_ratio": ratio.tolist(),
                "reference_ratio": ref.tolist(),
                "mid_radius_error_end": float(err[-1]),
                "mid_radius_error_max": float(np.max(np.abs(err))),
                "mid_pressure_pa": p.tolist(),
                "mid_pressure_ratio_end": float(p[-1] / (-mu * self.rate)) if later.any() else nan,
                "strain": float(self.rate * t[-1]), "radius_m": self.R0, "length_m": self.L0,
                "strain_rate_1_s": self.rate, "viscosity_pa_s": mu}


@dataclass
class ExtensionOptions:
    radius_mm: float = opt(0.5, help="filament radius R0 (mm)", check=Positive(),
                           flag="--radius-mm")
    length_mm: float = opt(4.0, help="filament length L0 between the end pieces (mm)",
                           check=Positive(), flag="--length-mm")
    strain_rate: float = opt(1.0, help="Hencky strain rate e (1/s)", check=Positive(),
                             flag="--strain-rate")
    strain: float = opt(0.5, help="Hencky strain e t at the end (-); the run lasts strain / e",
                        check=Positive(), flag="--strain")
    samples: int = opt(10, help="mid-radius samples over the run", check=Range(1, 10000, integer=True))


def _defaults(_options) -> dict:
    return coupled_pla_defaults(0.1, gravity_m_s2=0.0)


register(SceneEntry("extension", "a melt filament pulled apart at its ends (uniaxial extension)",
                    ExtensionOptions, lambda o: ExtensionScene(**asdict(o)), _defaults))
