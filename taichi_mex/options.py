"""Options (plain dataclasses, SI units unless a name says mm) and named presets.

Invalid values and combinations fail in :meth:`validate` with a message that says what to
change; nothing is checked inside the time loop.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields, replace

from taichi_mex.errors import UserInputError

SCHEMES = ("edac", "dfsph", "static")
VISCOSITY_MODELS = ("newtonian", "arrhenius", "cross_wlf")


@dataclass
class Material:
    """A polymer melt and its solid. Defaults: PLA.

    Sources: density 1240 kg/m^3 (NatureWorks Ingeo 2003D datasheet); glass transition
    55-65 degC (NETZSCH polymer database, DSC midpoint 63 degC); solid c_p ~1200 J/kg/K and
    k ~0.12 W/m/K at room temperature (Zmeskal et al., AIP Conf. Proc. 2305, 020022, 2020),
    melt c_p ~2.1 kJ/kg/K (Pyda et al. 2004): we use 1800 J/kg/K and 0.13 W/m/K over the
    printing range. Melt viscosity: Cross fits of PLA give eta0 = 1480-9460 Pa s at
    200-220 degC and n = 0.29-0.37 (Acierno & Patti, Materials 16, 7664, 2023, Table 1).
    The Cross-WLF set below is *constructed* to sit inside those ranges (eta0 = 2000 Pa s at
    210 degC, n = 0.30, tau* = 5e4 Pa, A2 = 51.6 K); it is not a published grade fit.
    """

    name: str = "PLA"
    density_kg_m3: float = 1240.0
    #: Newtonian viscosity, or the reference value for the Arrhenius model
    viscosity_pa_s: float = 1000.0
    viscosity_model: str = "newtonian"
    #: Arrhenius: eta(T) = eta_ref exp(E/R (1/T - 1/T_ref))
    arrhenius_activation_j_mol: float = 80e3
    arrhenius_reference_c: float = 220.0
    #: Cross-WLF (Moldflow form), zero-shear part D1 exp(-A1 (T - D2) / (A2 + T - D2))
    cross_n: float = 0.30
    cross_tau_star_pa: float = 5.0e4
    wlf_d1_pa_s: float = 2.94e9
    wlf_d2_k: float = 373.15
    wlf_a1: float = 20.86
    wlf_a2_k: float = 51.6
    specific_heat_j_kgk: float = 1800.0
    conductivity_w_mk: float = 0.13
    #: temperature-dependent c and k: ((T degC, value), ...) points, linear in between and
    #: constant beyond; empty = the constants above (physics/thermal.py)
    specific_heat_table: tuple = ()
    conductivity_table: tuple = ()
    glass_transition_c: float = 60.0
    #: below this the melt stops flowing and becomes a rigid solid (heat must be on);
    #: the glass transition is where PLA's viscosity diverges (Moldflow's "no-flow" temperature
    #: of amorphous grades sits at or just above Tg)
    no_flow_temperature_c: float = 60.0
    extrusion_temperature_c: float = 220.0
    emissivity: float = 0.92

    def zero_shear_viscosity(self, temperature_c: float) -> float:
        """eta0(T) in Pa s for the chosen model (Newtonian: constant)."""
        if self.viscosity_model == "newtonian":
            return self.viscosity_pa_s
        T = temperature_c + 273.15
        if self.viscosity_model == "arrhenius":
            Tr = self.arrhenius_reference_c + 273.15
            return self.viscosity_pa_s * math.exp(self.arrhenius_activation_j_mol / 8.314 * (1 / T - 1 / Tr))
        dT = T - self.wlf_d2_k
        return self.wlf_d1_pa_s * math.exp(-self.wlf_a1 * dT / (self.wlf_a2_k + dT))

    def validate(self) -> None:
        for name in ("density_kg_m3", "specific_heat_j_kgk", "conductivity_w_mk"):
            if not getattr(self, name) > 0:
                raise UserInputError(f"material {name} must be positive, got {getattr(self, name)}.")
        if not self.viscosity_pa_s >= 0 or (self.viscosity_pa_s == 0 and self.viscosity_model != "newtonian"):
            raise UserInputError(f"material viscosity must be positive (0 only for an inviscid "
                                 f"Newtonian fluid), got {self.viscosity_pa_s}.")
        if self.viscosity_model not in VISCOSITY_MODELS:
            raise UserInputError(f"Unknown viscosity model '{self.viscosity_model}'; choose "
                                 f"{', '.join(VISCOSITY_MODELS)}.")
        if not 0 <= self.emissivity <= 1:
            raise UserInputError(f"emissivity must lie in [0, 1], got {self.emissivity}.")
        if not 0 < self.cross_n <= 1:
            raise UserInputError(f"Cross-WLF power-law index n must lie in (0, 1], got {self.cross_n}.")


@dataclass
class EDACOptions:
    """Entropically damped artificial compressibility (Ramachandran & Puri 2019), as in
    PySPH's EDACScheme for free surfaces: summation density, no EOS, PEC integrator."""

    sound_speed_m_s: float = 6.0
    #: nu_edac = edac_alpha * h * c / 8 (PySPH default 0.5)
    edac_alpha: float = 0.5
    #: dt <= cfl * h / (c + |v|max)
    cfl: float = 0.25
    clamp_wall_pressure: bool = False


@dataclass
class DFSPHOptions:
    """Divergence-free SPH (Bender & Koschier 2015/2017) with implicit viscosity."""

    #: stop the density solve at this mean compression error (fraction: 5e-4 = 0.05 %)
    max_density_error: float = 5e-4
    #: ... and at this largest error of any particle (mature codes stop on the mean only,
    #: which a few badly compressed particles next to the moving nozzle hide in)
    max_density_error_local: float = 1e-2
    #: stop the divergence solve at this mean error of d(rho)/dt * dt / rho0
    max_divergence_error: float = 1e-3
    max_divergence_error_local: float = 1e-2
    #: after the density solve, sum the density at the step's new positions; while the densest
    #: melt is compressed more than this (fraction), solve again from that summed density,
    #: compression only, at most compression_corrections times. The solve's own check is the
    #: linear prediction rho + dt D(v): melt squeezed onto the plate under the nozzle overshot it
    #: to 1.8 % (unscaled single bead, dx = 0.05 mm), an O(dt^2) error. None: no check
    compression_check: float | None = 9e-3
    compression_corrections: int = 3
    min_iterations: int = 2
    max_iterations: int = 100
    #: True, False, or 'auto': off in creeping steps (every melt particle's nu dt / dx^2 >=
    #: DFSPH.creeping_diffusion), where the viscous solve, not inertia, sets the velocity; on
    #: the unscaled single bead it took 40 % of the wall time and changed the section by half
    #: to one spacing, area and density errors alike (README, Single bead)
    divergence_solve: bool | str = "auto"
    #: dt = cfl * 0.4 * spacing / |v|max (SPlisHSPlasH's form)
    cfl: float = 0.5
    max_dt_s: float = 1e-3
    viscosity_tolerance: float = 1e-3
    viscosity_max_iterations: int = 500
    #: the plate and nozzle are no-slip for the implicit viscosity solve
    no_slip: bool = True


@dataclass
class ThermalOptions:
    """Heat: Brookshaw conduction, Newton convection, Stefan-Boltzmann radiation."""

    enabled: bool = False
    convection_w_m2k: float = 0.0
    #: radiation only when asked: None = off, else the emissivity
    radiation_emissivity: float | None = None
    ambient_c: float = 20.0
    plate_temperature_c: float = 60.0
    #: 'colour_gradient' (default, calibrated) or 'eigenvalue' (the seed paper's Eq. 8)
    surface_method: str = "colour_gradient"


@dataclass
class RunOptions:
    """How a scene is discretised and integrated."""

    scheme: str = "dfsph"
    spacing_mm: float = 0.05
    #: 'cubic' or 'wendland_c2'; None = the scheme's choice
    kernel: str | None = None
    #: support radius / spacing; None = the scheme's choice
    support_factor: float | None = None
    gravity_m_s2: float = 9.81
    arch: str = "cpu"
    precision: str = "f32"
    cpu_threads: int | None = None
    #: write an HDF5 frame (and snapshots) every this many simulated seconds (None: 10 frames)
    output_every_s: float | None = None
    snapshot_field: str = "density"
    snapshots: bool = True
    plate_layers: int = 3
    #: extra plate and domain around the deposition, mm
    margin_mm: float = 1.0
    progress: bool = True
    #: abort if the largest speed exceeds this (m/s): a blow-up, not physics.
    #: None: 20 x the scene's speed scale (nozzle or gravity-wave speed), at least 1 m/s
    max_speed_m_s: float | None = None
    #: multiplies the stable time step; > 1 only to probe stability limits
    dt_factor: float = 1.0
    #: refuse a run whose estimated step count exceeds this (days of computing, usually an
    #: explicit scheme at a real melt viscosity); raise it to insist
    max_steps: int = 5_000_000
    #: creeping-flow scaling of the melt viscosity (all values, ratios kept): 'auto' picks the
    #: smallest factor that keeps the Reynolds number, the gravity number and the gravity
    #: slump over the run below ``creeping_limit`` (print scenes, DFSPH only), 1.0 = off
    viscosity_scale: float | str = "auto"
    creeping_limit: float = 0.05
    edac: EDACOptions = field(default_factory=EDACOptions)
    dfsph: DFSPHOptions = field(default_factory=DFSPHOptions)
    thermal: ThermalOptions = field(default_factory=ThermalOptions)

    @property
    def spacing_m(self) -> float:
        return self.spacing_mm * 1e-3

    def resolved_kernel(self) -> tuple[str, float]:
        """(kernel, support radius / spacing) with scheme defaults filled in."""
        if self.scheme == "edac":
            # PySPH's usual Wendland choice with h = 1.3 dx, support 2h
            return self.kernel or "wendland_c2", self.support_factor or 2.6
        if self.scheme == "static":  # heat only: Cleary & Monaghan used the cubic spline
            return self.kernel or "cubic", self.support_factor or 2.0
        return self.kernel or "cubic", self.support_factor or 2.0

    def validate(self) -> None:
        if self.scheme not in SCHEMES:
            raise UserInputError(f"Unknown scheme '{self.scheme}'; choose {', '.join(SCHEMES)}.")
        if not 1e-3 <= self.spacing_mm <= 100:
            raise UserInputError(f"Particle spacing {self.spacing_mm} mm is outside 0.001-100 mm.")
        kernel, factor = self.resolved_kernel()
        if kernel not in ("cubic", "wendland_c2"):
            raise UserInputError(f"Unknown kernel '{kernel}'; choose cubic or wendland_c2.")
        if not 1.5 <= factor <= 4.0:
            raise UserInputError(f"Support radius of {factor} spacings is outside 1.5-4.")
        if self.viscosity_scale != "auto" and not (isinstance(self.viscosity_scale, (int, float))
                                                    and 0 < self.viscosity_scale <= 1):
            raise UserInputError(f"viscosity_scale must be 'auto' or a number in (0, 1], got "
                                 f"{self.viscosity_scale!r}.")
        if not 0 < self.dt_factor <= 10:
            raise UserInputError(f"dt_factor {self.dt_factor} is outside (0, 10].")
        if self.plate_layers < 1:
            raise UserInputError("The plate needs at least one layer of particles.")
        if self.edac.sound_speed_m_s <= 0 or not 0 < self.edac.cfl <= 1:
            raise UserInputError("EDAC needs a positive sound speed and 0 < cfl <= 1.")
        if not 0 < self.dfsph.cfl <= 2:
            raise UserInputError("DFSPH cfl must lie in (0, 2].")
        check = self.dfsph.compression_check
        if check is not None and not (isinstance(check, (int, float)) and 0 < check <= 0.1):
            raise UserInputError(f"DFSPH compression_check is a fraction in (0, 0.1] (9e-3 = 0.9 %) "
                                 f"or None (off), got {check!r}.")
        if not (isinstance(self.dfsph.compression_corrections, int)
                and 0 <= self.dfsph.compression_corrections <= 20):
            raise UserInputError(f"DFSPH compression_corrections is a whole number in 0-20, got "
                                 f"{self.dfsph.compression_corrections!r}.")
        if self.dfsph.divergence_solve not in (True, False, "auto"):
            raise UserInputError(f"DFSPH divergence_solve is True, False or 'auto', got "
                                 f"{self.dfsph.divergence_solve!r}.")
        if self.thermal.surface_method not in ("colour_gradient", "eigenvalue"):
            raise UserInputError(f"Unknown surface method '{self.thermal.surface_method}'; choose "
                                 "colour_gradient or eigenvalue.")


PAPER_PRESET = {
    "description": "The seed paper's PySPH baseline: EDAC, c_s = 6 m/s, eta = 0.1 Pa s, "
                   "nozzle one diameter above the plate, 60 mm/s (gcode/paper_*.gcode).",
    "run": {"scheme": "edac", "edac": {"sound_speed_m_s": 6.0}},
    "material": {"viscosity_pa_s": 0.1, "viscosity_model": "newtonian"},
    "gcode": "paper_bead.gcode",
    "nozzle_height": "one_diameter",
    "nozzle_tip": False,
}

PRESETS = {"paper": PAPER_PRESET}

#: named resolutions for 0.2 mm layers (3, 4 and 6 particles across the layer height), picked
#: from the measured trade table in README.md; ``--resolution NAME`` or a spacing in mm
RESOLUTION_PRESETS = {
    "draft": {"run": {"spacing_mm": 0.0667}, "particles_per_layer": 3},
    "standard": {"run": {"spacing_mm": 0.05}, "particles_per_layer": 4},
    "fine": {"run": {"spacing_mm": 0.0333}, "particles_per_layer": 6},
}


def apply_overrides(obj, overrides: dict):
    """Return a copy of a dataclass with (nested) fields replaced from a dict."""
    names = {f.name for f in fields(obj)}
    changes = {}
    for key, value in overrides.items():
        if key not in names:
            raise UserInputError(f"Unknown option '{key}' for {type(obj).__name__}.")
        current = getattr(obj, key)
        if hasattr(current, "__dataclass_fields__") and isinstance(value, dict):
            changes[key] = apply_overrides(current, value)
        else:
            changes[key] = value
    return replace(obj, **changes)


def to_dict(obj) -> dict:
    return asdict(obj)
