"""Options: typed dataclasses, SI units unless a name says mm, with their checks and flags.

Every field is declared with :func:`opt`: a help text that states its unit, a check that
:func:`validate_fields` applies (so ``validate()`` covers every field), and optionally the
command-line flag and the flat sweep names that reach it. The command line, the TOML sweeps
and ``config.json`` are all generated from these declarations: a field added here reaches
all three without further edits. Nothing is checked inside the time loop.
"""

from __future__ import annotations

import math
from dataclasses import MISSING, asdict, dataclass, field, fields, is_dataclass, replace

from taichi_mex.errors import UserInputError


# ----------------------------------------------------------------------------- checks
class Check:
    """A predicate on one option value; ``problem(value)`` says what is wrong, or None."""

    def problem(self, value) -> str | None:
        raise NotImplementedError


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


class Range(Check):
    """A finite number in [lo, hi] (open ends with lo_open / hi_open; None: unbounded)."""

    def __init__(self, lo=None, hi=None, lo_open=False, hi_open=False, integer=False):
        self.lo, self.hi, self.lo_open, self.hi_open, self.integer = lo, hi, lo_open, hi_open, integer

    def problem(self, value):
        if self.integer and not (isinstance(value, int) and not isinstance(value, bool)):
            return "must be a whole number"
        if not _number(value):
            return "must be a finite number"
        lo_bad = self.lo is not None and (value <= self.lo if self.lo_open else value < self.lo)
        hi_bad = self.hi is not None and (value >= self.hi if self.hi_open else value > self.hi)
        if (lo_bad or hi_bad) and self.lo == 0 and self.hi is None:
            return "must be positive" if self.lo_open else "must not be negative"
        if lo_bad or hi_bad:
            left = "-inf" if self.lo is None else f"{self.lo:g}"
            right = "inf" if self.hi is None else f"{self.hi:g}"
            return (f"is outside {'(' if self.lo_open or self.lo is None else '['}{left}, "
                    f"{right}{')' if self.hi_open or self.hi is None else ']'}")
        return None


def Positive() -> Range:  # noqa: N802 - reads as a check in field declarations
    return Range(0.0, None, lo_open=True)


def NonNegative() -> Range:  # noqa: N802
    return Range(0.0, None)


class OneOf(Check):
    def __init__(self, *choices):
        self.choices = choices

    def problem(self, value):
        if any(value == c and type(value) is type(c) for c in self.choices):
            return None
        return "must be one of " + ", ".join(repr(c) for c in self.choices)


class Either(Check):
    """The value passes any of the checks (e.g. None or a positive number)."""

    def __init__(self, *checks):
        self.checks = checks

    def problem(self, value):
        problems = [c.problem(value) for c in self.checks]
        return None if any(p is None for p in problems) else " or ".join(p for p in problems if p)


class Text(Check):
    def problem(self, value):
        return None if isinstance(value, str) and value.strip() else "must be non-empty text"


class Flag(Check):
    def problem(self, value):
        return None if isinstance(value, bool) else "must be true or false"


class Table(Check):
    """((x, value), ...) points with increasing x and positive values; empty = off."""

    def problem(self, value):
        try:
            pts = [(float(a), float(b)) for a, b in value]
        except (TypeError, ValueError):
            return "must be a list of (temperature, value) pairs"
        if any(b2[0] <= b1[0] for b1, b2 in zip(pts, pts[1:])) or any(b <= 0 for _, b in pts):
            return "needs increasing temperatures and positive values"
        return None


NONE = OneOf(None)


def opt(default=MISSING, *, help: str, check: Check | None = None, flag: tuple | str | None = None,
        names: tuple = (), parse=None, implies: dict | None = None, const=MISSING,
        flag_help: str | None = None, repeat: bool = False, factory=None,
        flag_not: str | None = None):
    """A declared option field.

    ``help`` states the meaning and unit. ``flag``: the command-line spelling(s); ``parse``
    turns the flag's text into a value (default: the field's type); ``const``: a flag that
    takes no value and sets this one; ``flag_not``: a second such flag that sets the opposite
    of a boolean ``const``. ``names``: flat sweep names besides the dotted path.
    ``implies``: other options (dotted paths from the run description's root) set when this
    one is given by a user. ``flag_help``: the flag's own help where it differs (a flag that
    switches something off). A nested group of options is declared with ``factory``."""
    meta = {"help": help, "check": check, "flag": (flag,) if isinstance(flag, str) else flag,
            "flag_help": flag_help, "repeat": repeat,
            "names": tuple(names), "parse": parse, "implies": dict(implies or {}), "const": const,
            "flag_not": flag_not}
    if factory is not None:
        return field(default_factory=factory, metadata=meta)
    return field(default=default, metadata=meta)


def validate_fields(obj, path: str = "") -> None:
    """Apply every field's check, nested groups included; a problem names the option, its
    value, what is wrong and the field's help (with its unit)."""
    for f in fields(obj):
        value = getattr(obj, f.name)
        where = f"{path}{f.name}"
        if is_dataclass(value):
            validate_fields(value, where + ".")
            continue
        check = f.metadata.get("check")
        if check is None:
            raise TypeError(f"option {where} declares no check")  # a programming error
        problem = check.problem(value)
        if problem:
            raise UserInputError(f"Option {where} = {value!r} {problem} ({f.metadata['help']}).")


def unchecked_fields(cls, path: str = "") -> list[str]:
    """Fields declared without a check (the tests require none)."""
    out = []
    for f in fields(cls):
        default = f.default_factory() if f.default_factory is not MISSING else f.default
        if is_dataclass(default):
            out += unchecked_fields(type(default), f"{path}{f.name}.")
        elif not f.metadata.get("check"):
            out.append(path + f.name)
    return out


SCHEMES = ("edac", "dfsph", "static")
VISCOSITY_MODELS = ("newtonian", "arrhenius", "cross_wlf")
ARCHES = ("cpu", "gpu")
PRECISIONS = ("f32", "f64")
PICTURE_FIELDS = ("density", "pressure", "velocity", "temperature", "bead_id", "phase")

#: named resolutions for 0.2 mm layers (3, 4 and 6 particles across the layer height), picked
#: from the measured trade table (validation/trade); ``--resolution NAME`` or a spacing in mm
RESOLUTION_PRESETS = {
    "draft": {"run": {"spacing_mm": 0.0667}, "particles_per_layer": 3},
    "standard": {"run": {"spacing_mm": 0.05}, "particles_per_layer": 4},
    "fine": {"run": {"spacing_mm": 0.0333}, "particles_per_layer": 6},
}


def parse_resolution(text) -> float:
    """A spacing in mm, or a named resolution (draft, standard, fine)."""
    if isinstance(text, str) and text in RESOLUTION_PRESETS:
        return float(RESOLUTION_PRESETS[text]["run"]["spacing_mm"])
    try:
        return float(text)
    except (TypeError, ValueError):
        raise UserInputError(f"'{text}' is neither a spacing in mm nor one of "
                             f"{', '.join(RESOLUTION_PRESETS)}.") from None


def parse_viscosity_scale(text):
    """'off' (= 1, the real viscosity) or a factor in (0, 1]; 'auto' is retired."""
    if isinstance(text, str):
        low = text.strip().lower()
        if low == "auto":
            raise UserInputError(
                "--viscosity-scale auto was retired on 2026-12-06: it lowered a print's viscosity "
                "to speed up the split solve, and the coupled solve that prints now run solves "
                "creeping flow at any viscosity, in fewer iterations at the real one "
                "(validation/strands, strands_viscosity). Leave the option out (the real "
                "viscosity) or give a factor in (0, 1].")
        if low in ("off", "none"):
            return 1.0
        try:
            return float(low)
        except ValueError:
            raise UserInputError(f"the viscosity scale is a number in (0, 1] or 'off', "
                                 f"not '{text}'.") from None
    return text


def parse_optional_float(text):
    """A number, or 'none' / 'off' for None."""
    if isinstance(text, str):
        if text.strip().lower() in ("none", "off", "false"):
            return None
        try:
            return float(text)
        except ValueError:
            raise UserInputError(f"'{text}' is neither a number nor 'none'.") from None
    return text


def parse_point(text):
    """'X,Y,Z' in mm -> (x, y, z)."""
    if isinstance(text, str):
        try:
            x, y, z = (float(v) for v in text.split(","))
        except ValueError:
            raise UserInputError(f"A probe is X,Y,Z in mm (e.g. 12.5,10,0.1), not '{text}'.") from None
        return (x, y, z)
    return text


class Points(Check):
    """((x, y, z), ...) finite coordinates."""

    def problem(self, value):
        try:
            ok = all(len(p) == 3 and all(_number(c) for c in p) for p in value)
        except TypeError:
            ok = False
        return None if ok else "must be a list of (x, y, z) points in mm"


def parse_bool_or_auto(text):
    if isinstance(text, str):
        low = text.strip().lower()
        if low in ("true", "on", "yes", "1"):
            return True
        if low in ("false", "off", "no", "0"):
            return False
        return low
    return text


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

    name: str = opt("PLA", help="material name, for reports", check=Text())
    density_kg_m3: float = opt(1240.0, help="melt density (kg/m^3)", check=Positive(),
                               flag="--density")
    viscosity_pa_s: float = opt(
        1000.0, help="Newtonian viscosity, or the Arrhenius reference value (Pa s); the flag "
        "and the sweep name 'viscosity' also make the model Newtonian", check=NonNegative(),
        flag="--viscosity", names=("viscosity",), implies={"material.viscosity_model": "newtonian"})
    viscosity_model: str = opt("newtonian", help="newtonian, arrhenius or cross_wlf",
                               check=OneOf(*VISCOSITY_MODELS), names=("viscosity_model",))
    arrhenius_activation_j_mol: float = opt(
        80e3, help="Arrhenius activation energy E in eta(T) = eta_ref exp(E/R (1/T - 1/T_ref)) "
        "(J/mol)", check=NonNegative())
    arrhenius_reference_c: float = opt(220.0, help="Arrhenius reference temperature (degC)",
                                       check=Range(-273.15, None, lo_open=True))
    cross_n: float = opt(0.30, help="Cross-WLF power-law index n (-)",
                         check=Range(0.0, 1.0, lo_open=True))
    cross_tau_star_pa: float = opt(5.0e4, help="Cross-WLF critical stress tau* (Pa)",
                                   check=Positive())
    wlf_d1_pa_s: float = opt(2.94e9, help="Cross-WLF D1 in D1 exp(-A1 (T - D2) / (A2 + T - D2)) "
                             "(Pa s)", check=Positive())
    wlf_d2_k: float = opt(373.15, help="Cross-WLF D2 (K)", check=Positive())
    wlf_a1: float = opt(20.86, help="Cross-WLF A1 (-)", check=Positive())
    wlf_a2_k: float = opt(51.6, help="Cross-WLF A2 (K)", check=Positive())
    specific_heat_j_kgk: float = opt(1800.0, help="specific heat c (J/kg/K)", check=Positive())
    conductivity_w_mk: float = opt(0.13, help="thermal conductivity k (W/m/K)", check=Positive())
    specific_heat_table: tuple = opt(
        (), help="temperature-dependent c: ((T degC, J/kg/K), ...), linear in between, constant "
        "beyond; empty = the constant", check=Table())
    conductivity_table: tuple = opt(
        (), help="temperature-dependent k: ((T degC, W/m/K), ...); empty = the constant",
        check=Table())
    glass_transition_c: float = opt(60.0, help="glass transition (degC)",
                                    check=Range(-273.15, None, lo_open=True))
    no_flow_temperature_c: float = opt(
        60.0, help="below this the melt becomes a rigid solid, with heat on (degC); PLA's "
        "viscosity diverges at the glass transition", check=Range(-273.15, None, lo_open=True))
    extrusion_temperature_c: float = opt(
        220.0, help="melt temperature at the nozzle (degC): the inlet temperature with heat on, "
        "and where temperature-dependent viscosity is evaluated", check=Range(-273.15, None, lo_open=True),
        names=("nozzle_temperature_c",))
    emissivity: float = opt(0.92, help="surface emissivity (-)", check=Range(0.0, 1.0))
    solid_density_kg_m3: float = opt(1240.0, help="room-temperature solid density (kg/m^3; for "
                                     "reports: the melt density sets the mass)", check=Positive())
    bulk_modulus_pa: float = opt(
        1.5e9, help="melt bulk modulus K (Pa): the coupled solve's continuity rows let the "
        "melt's volume change by dp / K, as it does (physics/stokes.py, 'Compressibility'); "
        "Tait's law gives K = B(T) / 0.0894, B ~ 100-200 MPa for polymer melts", check=Positive())
    surface_tension_n_m: float = opt(0.035, help="melt surface tension (N/m; recorded, not yet "
                                     "modelled)", check=NonNegative())

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
        validate_fields(self, "material.")
        if self.viscosity_pa_s == 0 and self.viscosity_model != "newtonian":
            raise UserInputError("material viscosity must be positive (0 only for an inviscid "
                                 "Newtonian fluid).")


@dataclass
class EDACOptions:
    """Entropically damped artificial compressibility (Ramachandran & Puri 2019), as in
    PySPH's EDACScheme for free surfaces: summation density, no EOS, PEC integrator."""

    sound_speed_m_s: float = opt(6.0, help="artificial sound speed c_s (m/s)", check=Positive(),
                                 flag="--sound-speed", names=("sound_speed",))
    edac_alpha: float = opt(0.5, help="nu_edac = edac_alpha h c_s / 8 (-; PySPH's default 0.5)",
                            check=NonNegative())
    cfl: float = opt(0.25, help="dt <= cfl h / (c_s + |v|max) (-)",
                     check=Range(0.0, 1.0, lo_open=True))
    clamp_wall_pressure: bool = opt(False, help="clamp negative wall pressure to zero", check=Flag())
    list_skin: float = opt(0.15, help="Verlet skin of the neighbour lists as a fraction of the "
                           "support radius (-): EDAC steps move particles so little that lists "
                           "built with it last dozens of steps", check=Range(0.0, 1.0))


@dataclass
class DFSPHStabilisers:
    """Stabilisers of the split solve (DFSPH) that come from no cited paper, kept for the
    inertial scenes it still serves (hydrostatic, shear): without the incremental pressure and
    its interior tension the papers' solve left the hydrostatic column's pressure 23-53 % off
    (physics/dfsph.py). A creeping melt, for which the others were added, takes the coupled
    solve; the split solve refuses it (run.dfsph.creeping_diffusion). None deletes or clamps
    melt; the creeping-only ones (the closing-speed cap, tension's difference form and its
    release) and the droplet ejection and speed clamp are gone (spec.REMOVED_OPTIONS)."""

    tension_relaxation: float = opt(
        0.2, help="inside the melt the density solve also corrects expansions, this fraction per "
        "step (-; the unscaled single bead blew up at 0.3-1.0)", check=Range(0.0, 1.0))
    divergence_tension: str = opt(
        "interior", help="where the divergence solve also removes expansion rates: 'none' (the "
        "paper: compression only), 'interior' (away from the free surface and the nozzle) or "
        "'everywhere'", check=OneOf("none", "interior", "everywhere"))
    pressure_memory_loss: float = opt(
        0.05, help="fraction of last step's summed pressure the predictor forgets (-): noise of "
        "the toleranced solves would otherwise random-walk from step to step; the density "
        "solve's relative_residual makes it restore what it forgot", check=Range(0.0, 1.0))
    shifting: float = opt(
        0.0, help="particle shifting D = shifting dx^2 per step (-; Lind et al. 2012); 0.5 "
        "wrecked the hydrostatic pressure (56 % error)", check=NonNegative())
    surface_offset_h: float = opt(
        0.15, help="melt whose neighbourhood centre lies more than this fraction of the support "
        "radius off the particle counts as free surface and takes no tension (-)",
        check=Range(0.0, 1.0, lo_open=True))
    surface_min_neighbours: int = opt(
        20, help="melt with fewer neighbours than this counts as free surface and takes no "
        "tension, nor a divergence correction (-)", check=Range(1, 200, integer=True))


@dataclass
class DFSPHOptions:
    """Divergence-free SPH (Bender & Koschier 2015/2017) with implicit viscosity."""

    max_density_error: float = opt(
        5e-4, help="stop the density solve at this mean compression error (fraction: 5e-4 = "
        "0.05 %)", check=Range(0.0, 0.1, lo_open=True))
    max_density_error_local: float = opt(
        1e-2, help="... and at this largest error of any particle (fraction; mature codes stop "
        "on the mean only, which a few badly compressed particles next to the moving nozzle "
        "hide in)", check=Range(0.0, 0.5, lo_open=True))
    max_divergence_error: float = opt(
        1e-3, help="stop the divergence solve at this mean error of d(rho)/dt dt / rho0 "
        "(fraction)", check=Range(0.0, 0.1, lo_open=True))
    max_divergence_error_local: float = opt(
        1e-2, help="... and at this largest error of any particle (fraction)",
        check=Range(0.0, 0.5, lo_open=True))
    min_iterations: int = opt(2, help="pressure solves run at least this many iterations",
                              check=Range(0, 1000, integer=True))
    max_iterations: int = opt(100, help="pressure solves stop after this many iterations",
                              check=Range(1, 100000, integer=True))
    divergence_solve: bool | str = opt(
        "auto", help="split solve: true, false or 'auto': off in creeping steps (nu dt / dx^2 "
        ">= creeping_diffusion), where the viscous solve, not inertia, sets the velocity",
        check=OneOf(True, False, "auto"), parse=parse_bool_or_auto)
    cfl: float = opt(0.5, help="dt = cfl 0.4 spacing / u (-; SPlisHSPlasH's form), u the speed "
                     "that time_step_speed names", check=Range(0.0, 2.0, lo_open=True))
    time_step_speed: str = opt(
        "relative", help="the speed u of the CFL bound: 'relative', that of melt against its "
        "neighbours and of anything closing on it (a melt riding with the nozzle across a "
        "travel move takes long steps), or 'absolute', the fastest melt or wall (the rule "
        "before 2026-12-07, for comparison)", check=OneOf("relative", "absolute"),
        flag="--time-step-speed", names=("time_step_speed",))
    max_dt_s: float = opt(1e-3, help="largest time step (s)", check=Positive())
    viscosity_tolerance: float = opt(1e-3, help="relative residual the implicit viscosity "
                                     "solve stops at (-)", check=Range(0.0, 1.0, lo_open=True, hi_open=True))
    viscosity_max_iterations: int = opt(500, help="the implicit viscosity solve stops after this "
                                        "many CG iterations", check=Range(1, 100000, integer=True))
    no_slip: bool = opt(True, help="plate and nozzle are no-slip walls for the viscosity solve",
                        check=Flag())
    relative_residual: float | None = opt(
        0.1, help="the density solve also runs until its preconditioned "
        "residual norm has fallen by this factor (-; CG only; None: stop on the absolute errors "
        "alone). The summed "
        "pressure is a running sum of the solves' increments; with absolute stops alone a "
        "smooth error of it (the hydrostatic gradient) leaves too little density error to be "
        "corrected, and which part of it survives depended on rounding (the hydrostatic "
        "tank's gradient error read 0.19-0.41 for reduction blocks of 256, 1024 and 64)",
        check=Either(NONE, Range(0.0, 1.0, lo_open=True)), parse=parse_optional_float)
    method: str = opt("cg", help="pressure solver: 'cg' (Jacobi-preconditioned conjugate "
                      "gradients) or 'jacobi' (the papers' relaxed sweeps)",
                      check=OneOf("cg", "jacobi"))
    jacobi_omega: float = opt(0.5, help="relaxation of the 'jacobi' method (-)",
                              check=Range(0.0, 1.0, lo_open=True))
    cg_chunk: int = opt(4, help="solver iterations per kernel launch (unrolled; iterations "
                        "after convergence do no work)", check=Range(1, 64, integer=True))
    serial_rows: int | None = opt(
        None, help="on a CPU, the coupled solve's loops over its rows' own vectors (copies, "
        "updates, block sums) run on the calling thread below this many melt rows (rows; 0: "
        "always in parallel; None: 65,536). Each parallel loop is a hand-off to Taichi's thread "
        "pool, 0.05-0.07 ms on the 2-core test machine, while such a loop over 16,000 rows "
        "takes 0.017 ms on one thread (2026-12-06). A loop over the neighbours follows "
        "serial_pair_rows. Results agree to the solve's tolerance: to the bit on the squeeze "
        "film (test), while on benchy's window the two compiled loops rounded differently "
        "(32.4 against 32.9 GMRES iterations a step over 691 steps)",
        check=Either(NONE, Range(0, 10**9, integer=True)))
    serial_pair_rows: int | None = opt(
        None, help="on a CPU, the coupled solve's loops over the melt rows' neighbours (the "
        "operator, the inner solve's, the pressure gradient, Gram-Schmidt's sweeps) run on the "
        "calling thread below this many melt rows, and every loop with them (rows; 0: always "
        "in parallel; None: 4,096 on more than one thread, never in parallel on one). On 2 "
        "cores, the same steps (2026-12-06): the paper block's 8,896 melt rows 36 s in "
        "parallel against 51-53 s on one thread; the standard bead (up to 3,276 rows) 55.5 s "
        "from 2,000 rows against 54.6 s on one thread and 59.6 s always in parallel; the "
        "draft bead (1,376) 19.4 s on one thread against 27.8 s in parallel",
        check=Either(NONE, Range(0, 10**9, integer=True)))
    density_compression_only: bool = opt(
        False, help="the density solve corrects compression only, everywhere, as in the paper "
        "(with tension inside the melt allowed, see stabilisers.tension_relaxation)",
        check=Flag())
    max_travel_spacings: float = opt(
        0.5, help="a step whose pressure solve leaves melt moving more than this many spacings "
        "is redone with half the time step (-)", check=Positive())
    step_retries: int = opt(4, help="at most this many halvings of one step",
                            check=Range(0, 30, integer=True))
    creeping_solve: str = opt(
        "coupled", help="how a step solves viscosity and pressure: 'coupled' (in one "
        "saddle-point solve, physics/stokes.py: the melt's creeping flow, with no stabiliser "
        "and no deletion, an unconverged step halved or the run stopped; the default) or "
        "'split' (DFSPH, Bender & Koschier 2017, with Weiler et al.'s 2018 implicit viscosity "
        "before the pressure solves, physics/dfsph.py: for inertial flows, the hydrostatic "
        "and shear scenes' default; refused where the melt creeps, since there the split "
        "leaves an error the size of the solution)",
        check=OneOf("split", "coupled"), flag="--creeping-solve", names=("creeping_solve",))
    creeping_diffusion: float = opt(
        10.0, help="a step counts as creeping where nu dt / dx^2 >= this (-): viscous diffusion "
        "crosses about 3 spacings in the step, so inertia is gone within it. A run may then "
        "skip a span in which nothing drives the melt; the split solve refuses a run whose "
        "largest step would be creeping", check=Positive())
    stokes_momentum_tolerance: float = opt(
        3e-4, help="coupled solve: velocity error it stops at, relative to the step's "
        "velocities (-): the momentum rows' residual and the motion the pressure error the "
        "continuity rows leave would cause (each step solves afresh, so the error is not "
        "inherited; physics/stokes.py, \"Tolerance\"). A residual's measure: on a film whose "
        "pressure memory carries noise, the velocities' true error was 25x it (2.5 % at "
        "3e-4, 7.5 % at 1e-3); at 1e-3 the standard bead came out 2 % wider and benchy's "
        "window flung a particle past the speed limit (2026-12-04)",
        check=Range(0.0, 0.1, lo_open=True))
    stokes_density_tolerance: float = opt(
        3e-4, help="coupled solve: largest density error dt |D(u) - s| a step may leave (-). "
        "Compression it leaves the next step's kernel sum removes; expansion stays (at 1e-3 "
        "the draft bead's interior kernel sums were as close to rho0 as at 1e-5, 0.0082 off "
        "on average)",
        check=Range(0.0, 0.1, lo_open=True))
    stokes_restart: int = opt(
        200, help="coupled solve: GMRES restart length (Krylov vectors kept, 96 bytes per melt "
        "particle each). A solve restarted before it converges throws its Krylov space away and "
        "slows down: at 40 the bore flow at 8 per radius under Weiler's sum did not converge in "
        "20,000 iterations and converges in 193 at 200; the collapse's late steps (R = H = 3 mm, "
        "0.2 mm, 1 Pa s) took 344 iterations at 40 against 135 at 120. It sets the memory and "
        "the cost, not the answer",
        check=Range(2, 500, integer=True))
    stokes_norm: str = opt(
        "criterion", help="coupled solve: the norm GMRES minimises the residual in: "
        "'criterion', the one its stop reads (the velocity error the residual stands for, "
        "through the momentum rows' diagonal blocks and the motion the continuity rows' "
        "pressure error causes, and the density error on the same scale; physics/stokes.py, "
        "\"Norm\"), at one more pressure-gradient sum an iteration; or 'euclidean'. Benchy's "
        "4 x 4 mm window, side by side (2026-12-04): 17.9 / 102 GMRES / inner iterations a "
        "step at the defaults against 34.6 / 257 Euclidean at the earlier ones (inner 0.1, "
        "tolerances 1e-3)",
        check=OneOf("criterion", "euclidean"))
    stokes_gram_schmidt_passes: int = opt(
        1, help="coupled solve: classical Gram-Schmidt passes a GMRES iteration orthogonalises "
        "its new vector with (1 or 2). It sets the cost, not the answer: the true residual at "
        "each restart decides the stop (physics/stokes.py, \"Orthogonalisation\"). The paper "
        "block's steps 1.03-1.16x faster with 1 (2026-12-06, 2 cores), the same iterations",
        check=Range(1, 2, integer=True))
    stokes_initial_guess: str = opt(
        "previous", help="coupled solve: where GMRES starts, 'previous' (the melt's present "
        "velocity v_n) or 'extrapolated' (each melt particle's from its last two steps, "
        "v_n + (dt / dt_n-1)(v_n - v_n-1)). Both stop at the same tolerances; what the extrapolated "
        "start saves changes sign with the step and the density source (test_idle's print, "
        "2026-12-07: 10.2 / 26.1 against 10.1 / 29.2 GMRES / inner a step with the default "
        "two-way source, 9.0 / 26.0 against 8.4 / 23.4 one way), and it carries forward the "
        "error the stop reads weakly (benchy's window flung more melt; physics/stokes.py, "
        "\"Initial guess\")",
        check=OneOf("previous", "extrapolated"))
    stokes_max_iterations: int = opt(20000, help="coupled solve: an unconverged step is halved "
                                     "after this many GMRES iterations",
                                     check=Range(1, 10**7, integer=True))
    stokes_preconditioner: str = opt(
        "block_triangular", help="coupled solve: 'block_triangular' (the pressure from the "
        "Schur complement's approximation, then the viscous rows solved for it by an inner "
        "conjugate-gradient solve; flexible GMRES) or 'block_diagonal' (3 x 3 diagonal blocks "
        "and the Schur approximation; GMRES)", check=OneOf("block_triangular", "block_diagonal"),
        flag="--stokes-preconditioner")
    stokes_inner_tolerance: float = opt(
        0.3, help="coupled solve, block_triangular: the inner viscous solve stops when its "
        "residual has fallen by this factor (-); it sets the cost, not the answer, which the "
        "outer tolerances decide. Benchy's 4 x 4 mm window (2026-12-04, GMRES in the stop's "
        "norm, tolerances 3e-4): 17.9 / 102 GMRES / inner iterations a step; the standard "
        "bead 20.3 / 56 at 0.3 against 13.8 / 81 at 0.1 (tolerances 1e-3). In the Euclidean "
        "norm 0.3 stalled (a print of tests/test_idle at t = 0.551 s). From 1e-4: on Weiler's "
        "sum its neighbour pass is f32 (physics/stokes.py, 'Inner precision')",
        check=Range(1e-4, 1.0, hi_open=True))
    stokes_inner_max_iterations: int = opt(
        100, help="coupled solve, block_triangular: cap on the inner viscous solve's "
        "iterations per outer iteration", check=Range(1, 10**5, integer=True))
    stokes_inner_operator: str = opt(
        "auto", help="coupled solve, block_triangular, with the surface traction: the "
        "operator the inner viscous solve inverts. 'weiler2018': Weiler's pair sum, one pass "
        "over the melt an iteration; 'system': the system's own viscous block, the "
        "strain-energy form, four passes an iteration but far fewer GMRES iterations where "
        "the free surface is much of the melt (the collapse at 0.2 mm: 45 against 566 a step "
        "on the thin current, 96 against 71 on the tall cylinder). 'auto': each solve takes "
        "the operator whose latest solve cost fewer passes over the melt, and tries the other "
        "again once the one in use costs twice what it did when chosen (counts, not timings: "
        "a run makes the same choices every time); on that collapse it ran the form on 75 "
        "of 170 steps (two early tries, then from the 98th on), 1,109 s against 2,264 s on "
        "the form throughout (physics/stokes.py, \"block-triangular preconditioner\"; "
        "validation/peer). 'system' is refused where it would change nothing (without the "
        "traction both are the pair sum; block_diagonal has no inner solve); 'auto' is "
        "the pair sum there",
        check=OneOf("weiler2018", "system", "auto"), flag="--stokes-inner-operator")
    stokes_surface_traction: bool = opt(
        True, help="coupled solve: the free surface is traction-free, -p + 2 mu n.D.n = 0 (the "
        "viscous term is the derivative of a dissipation built on the corrected strain rate, "
        "whose boundary term is the pressure's, physics/stokes.py); off: the viscous pair sum "
        "(stokes_viscous_isotropic_share), whose surface carries no viscous flux. Off in a "
        "print by default: with it the bundled bead comes out 1.5x as wide at draft and at "
        "standard, for a reason not yet found (physics/stokes.py has what was measured and "
        "tried), at 3.4-5.1x the cost with "
        "stokes_inner_operator = 'system' (2026-12-05)",
        check=Flag(),
        flag="--no-surface-traction", const=False, flag_not="--surface-traction",
        flag_help="coupled solve: the viscous pair sum at the free surface, which carries no "
        "viscous flux, in place of the traction-free condition (a print's default)")
    stokes_wall_ghost: str = opt(
        "adami", help="coupled solve without the surface traction: the velocity a wall "
        "particle shows a melt row's viscous pair terms. 'adami': Adami, Hu & Adams's (2012) "
        "mirror 2 v_b - (the melt's Shepard average), exact for a linear profile only: "
        "Poiseuille's parabola across a 4-layer gap comes out 1.08x its amplitude and the "
        "squeeze film 0.80 of Stefan's force. 'quadratic': next to a wall whose surface and "
        "normal its geometry gives (the plate, a nozzle's flat face), the row's melt in reach "
        "fitted along the normal by a parabola through the wall's velocity at its surface "
        "(weighted least squares), shown at the wall particle's depth; Adami's mirror "
        "elsewhere: the parabola 0.996x, the squeeze film 0.90 (validation/couette). For "
        "scenes measured by one solve at a fixed geometry only (couette, squeeze-film): a "
        "film whose walls slid past it blew up at 2 ms under it, so scenes that run in time "
        "refuse it (physics/stokes.py)",
        check=OneOf("adami", "quadratic"), flag="--wall-ghost")
    stokes_surface_rows: str = opt(
        "continuity", help="coupled solve without the surface traction: what the rows of melt "
        "on the free surface (Marrone et al.'s 2010 test) hold. 'continuity': the same "
        "continuity row as the melt inside, which leaves their pressure to it (measured at the "
        "bundled bead's free surface: a median -207 kPa where traction-free asks -68, "
        "validation/strands); 'traction': the traction-free condition -p + 2 mu n.D.n = 0 in "
        "its place, n Marrone's normal and D from Bonet & Lok's corrected gradient of the "
        "velocities (the free-surface rows of incompressible SPH, Shao & Lo 2003, with the "
        "viscous normal stress in the pressure; physics/stokes.py, \"Free-surface rows\"): the "
        "die's jet then carries the die's flux, but the surface's particles, held by no "
        "continuity row, compress (the bundled bead's up to 1.22 rho0) and strands come out "
        "wider (+19 / +23 % at draft / standard)",
        check=OneOf("continuity", "traction"), flag="--surface-rows")
    stokes_viscous_isotropic_share: float | None = opt(
        None, help="coupled solve without the surface traction: the share of Morris, Fox & "
        "Zhu's (1997) Laplacian of the whole velocity difference in each viscous pair term, the "
        "rest Weiler et al.'s (2018) link-projected sum (-). Both are Espanol & Revenga's "
        "(2003) pair form of the Newtonian stress; the share w stands for a bulk viscosity "
        "zeta = (5/3 - 2 w) mu, which a divergence-free flow does not feel. 0: Weiler's sum "
        "alone, whose rows are held across a plane of links by their inertia only (benchy's "
        "window flung such a particle at 1.44 m/s); 0.5: div(mu (grad u + grad u^T)); 1: "
        "Morris's alone, which lets melt slip under a wall (the bundled bead 0.635 mm wide at "
        "standard). Default (none given): 0.1 where the pair sum is the system's viscous "
        "term (physics/stokes.py, \"Operators\")",
        check=Either(NONE, Range(0.0, 1.0)), parse=parse_optional_float,
        flag="--viscous-isotropic-share")
    stokes_zero_energy_control: float = opt(
        1.0, help="coupled solve with the surface traction: weight of Ganzenmueller's (2015) "
        "hourglass term, Weiler's pair dissipation of what the corrected velocity gradient "
        "does not see (-); 0 leaves particle-scale zigzags undamped (physics/stokes.py)",
        check=Range(0.0, 100.0))
    stokes_density_source: str = opt(
        "two-way", help="coupled solve: what the continuity rows remove besides divergence: "
        "'summation', the compression the kernel sum shows, min(1 - rho / rho0, 0) / dt "
        "(Bender & Koschier 2017); 'two-way', the kernel sum's error both ways, "
        "(1 - rho / rho0) / dt, on particles whose kernel is full (interior by Marrone et al.'s "
        "2010 free-surface test, with his eigenvalue over 0.75; Shao & Lo's 2003 "
        "density-invariant source), compression only elsewhere: the surface, the layer under "
        "it and holes in the melt; 'none', nothing (divergence-free steps). The "
        "kernel sum also reads a stretched arrangement as compressed (validation/extension: "
        "+6 % at a Hencky strain of 0.36)",
        check=OneOf("summation", "two-way", "none"), flag="--density-source")
    stokes_compressible: bool = opt(
        True, help="coupled solve: the melt's volume changes by dp / K (material.bulk_modulus_pa) "
        "in a step; off: incompressible rows, which a fragment of one or two particles at the "
        "edge of its neighbours' kernels makes near-singular (benchy's window stalled at "
        "t = 181.365 s, physics/stokes.py)", check=Flag())
    stabilisers: DFSPHStabilisers = opt(help="stabilisers of the 'split' solve, for inertial "
                                        "flows (no cited source; 'coupled' needs none)",
                                        factory=DFSPHStabilisers)


@dataclass
class ThermalOptions:
    """Heat: Brookshaw conduction, Newton convection, Stefan-Boltzmann radiation."""

    enabled: bool = opt(False, help="simulate temperature", check=Flag(), flag="--thermal",
                        const=True, names=("thermal",))
    convection_w_m2k: float = opt(0.0, help="convective heat transfer coefficient h_c "
                                  "(W/m^2/K); switches heat on", check=NonNegative(),
                                  flag="--convection", names=("convection_w_m2k",),
                                  implies={"run.thermal.enabled": True})
    radiation_emissivity: float | None = opt(
        None, help="radiate to ambient with this emissivity (-), None = no radiation; switches "
        "heat on", check=Either(NONE, Range(0.0, 1.0)), flag="--radiation",
        names=("radiation_emissivity",), parse=parse_optional_float,
        implies={"run.thermal.enabled": True})
    ambient_c: float = opt(20.0, help="ambient temperature (degC); switches heat on",
                           check=Range(-273.15, None, lo_open=True), flag="--ambient",
                           names=("ambient_c",), implies={"run.thermal.enabled": True})
    plate_temperature_c: float = opt(60.0, help="build plate temperature (degC); switches heat on",
                                     check=Range(-273.15, None, lo_open=True),
                                     flag="--plate-temperature", names=("plate_temperature_c",),
                                     implies={"run.thermal.enabled": True})
    surface_method: str = opt("colour_gradient", help="free-surface area estimate for losses: "
                              "colour_gradient (calibrated) or eigenvalue (the seed paper's Eq. 8)",
                              check=OneOf("colour_gradient", "eigenvalue"), flag="--surface-method")


@dataclass
class RunOptions:
    """How a scene is discretised and integrated."""

    scheme: str = opt("dfsph", help="pressure solver: dfsph (implicit pressure and viscosity), "
                      "edac (the seed paper's explicit baseline) or static (heat only)",
                      check=OneOf(*SCHEMES), flag=("--scheme", "--solver"), names=("scheme",))
    spacing_mm: float = opt(0.05, help="particle spacing (mm), or draft / standard / fine "
                            "(3 / 4 / 6 particles across a 0.2 mm layer)",
                            check=Range(1e-3, 100.0), flag=("--resolution", "--spacing-mm"),
                            names=("spacing_mm", "resolution"), parse=parse_resolution)
    kernel: str | None = opt(None, help="'cubic' or 'wendland_c2'; None = the scheme's choice",
                             check=Either(NONE, OneOf("cubic", "wendland_c2")))
    support_factor: float | None = opt(None, help="support radius / spacing (-); None = the "
                                       "scheme's choice", check=Either(NONE, Range(1.5, 4.0)))
    gravity_m_s2: float = opt(9.81, help="gravity (m/s^2, pointing -z)", check=NonNegative())
    arch: str = opt("cpu", help="cpu or gpu (CUDA or Vulkan, whichever Taichi finds)", check=OneOf(*ARCHES), flag="--arch",
                    names=("arch",))
    precision: str = opt("f32", help="floating-point precision of the particle state",
                         check=OneOf(*PRECISIONS), flag="--precision", names=("precision",))
    cpu_threads: int | None = opt(None, help="CPU threads (None: all cores)",
                                  check=Either(NONE, Range(1, 4096, integer=True)),
                                  flag="--threads", names=("cpu_threads",))
    output_every_s: float | None = opt(
        None, help="write an HDF5 frame every this many simulated seconds (None: 10 frames)",
        check=Either(NONE, Positive()), flag="--output-every", names=("output_every",))
    snapshot_every_s: float | None = opt(
        None, help="also write PNG snapshots every this many simulated seconds (None: at the "
        "end only)", check=Either(NONE, Positive()), flag="--snapshot-every")
    snapshot_field: str = opt("density", help="field the pictures are coloured by: density, "
                              "pressure, velocity, temperature (with heat), bead_id or phase",
                              check=OneOf(*PICTURE_FIELDS), flag="--field")
    snapshots: bool = opt(True, help="write PNG snapshots", check=Flag(), flag="--no-snapshots",
                          const=False, names=("snapshots",), flag_help="skip the PNG snapshots")
    probes_mm: tuple = opt((), help="points (x, y, z in mm, the G-code's coordinates) where "
                           "temperature and velocity are recorded into probes.csv; repeat the flag",
                           check=Points(), flag="--probe", parse=parse_point, repeat=True)
    probe_every_s: float | None = opt(None, help="probe sampling interval (s; None: 200 samples "
                                      "over the run)", check=Either(NONE, Positive()))
    skip_idle: bool = opt(True, help="while the nozzle is outside the domain and the melt creeps, "
                          "advance heat alone (or jump, without heat) to the nozzle's return; a span "
                          "is skipped only where the melt's gravity slump over it stays below "
                          "creeping_limit", check=Flag(), flag="--no-skip-idle", const=False,
                          flag_help="simulate the flow while the nozzle is away too")
    profile: bool = opt(False, help="time each phase of the step (neighbour search, each solve, "
                        "output) into summary.json's phase_seconds; waits for the device at each "
                        "phase, so a few per cent slower", check=Flag(), flag="--profile", const=True)
    animation: bool = opt(False, help="write animation.mp4 of the deposition (a GIF where no "
                          "encoder is available)", check=Flag(), flag="--animation", const=True)
    animation_frames: int = opt(60, help="frames of the animation, when output_every_s is not "
                                "given (it then also sets the HDF5 frames)",
                                check=Range(2, 10000, integer=True))
    plate_layers: int | None = opt(
        None, help="particle layers of the build plate and tank walls; None: as many as the "
        "kernel reaches (the support radius in spacings, rounded up: 2 for DFSPH's cubic "
        "spline, 3 for EDAC's Wendland), since deeper layers enter no sum",
        check=Either(NONE, Range(1, 50, integer=True)))
    margin_mm: float = opt(
        1.0, help="how far beyond the deposition the run follows the nozzle's tip face (mm); "
        "the plate and the domain reach one tip radius further, and where the nozzle leaves "
        "that box (a window) one bore diameter more (scenes/print.py)", check=NonNegative())
    progress: bool = opt(True, help="show a progress bar", check=Flag(), flag="--quiet",
                         const=False, flag_help="no progress bar")
    max_speed_m_s: float | None = opt(
        None, help="abort if the largest speed exceeds this (m/s): a blow-up, not physics; "
        "None: 20 x the scene's speed scale, at least 1 m/s", check=Either(NONE, Positive()))
    dt_factor: float = opt(1.0, help="multiplies the time step's limits (-): > 1 trades the "
                           "accuracy of the particles' motion for fewer steps under the coupled "
                           "creeping solve (validation/trade, 'The time step as a trade'), and "
                           "probes stability under the explicit schemes",
                           check=Range(0.0, 10.0, lo_open=True),
                           flag="--dt-factor", names=("dt_factor",))
    max_steps: int = opt(5_000_000, help="refuse a run whose estimated step count exceeds this "
                         "(days of computing, usually an explicit scheme at a real melt "
                         "viscosity); raise it to insist", check=Range(1, None, integer=True))
    viscosity_scale: float = opt(
        1.0, help="factor on the melt's viscosity as the flow is solved (-): 'off' or 1 (the "
        "default) runs the real melt, a factor in (0, 1] a thinner one. Creeping strands keep "
        "their shape either way and the coupled solve needs fewer iterations at the real "
        "viscosity (validation/strands, strands_viscosity), so a factor below 1 buys nothing "
        "but inertia and gravity slump, which every run reports as its creeping numbers",
        check=Range(0.0, 1.0, lo_open=True), flag="--viscosity-scale",
        names=("viscosity_scale",), parse=parse_viscosity_scale)
    creeping_limit: float = opt(0.05, help="largest gravity slump rho g L T / eta over an idle "
                                "span (nozzle away) that skip_idle may jump (-)",
                                check=Range(0.0, 1.0, lo_open=True))
    edac: EDACOptions = opt(help="EDAC scheme", factory=EDACOptions)
    dfsph: DFSPHOptions = opt(help="DFSPH scheme and implicit viscosity", factory=DFSPHOptions)
    thermal: ThermalOptions = opt(help="heat", factory=ThermalOptions)

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

    def wall_layers(self) -> int:
        """Particle layers of walls: plate_layers, or the kernel's reach in spacings."""
        if self.plate_layers is not None:
            return self.plate_layers
        return int(math.ceil(self.resolved_kernel()[1] - 1e-9))

    def validate(self) -> None:
        validate_fields(self, "run.")
        d = self.dfsph
        coupled = self.scheme == "dfsph" and d.creeping_solve == "coupled"
        # settings of the pair sum (the coupled solve without the surface traction), each
        # refused where it would change nothing or run something else under its name
        pair_sum_only = (
            ("stokes_viscous_isotropic_share", d.stokes_viscous_isotropic_share is not None,
             "the pair sum's viscous term, which the surface traction's strain-energy form "
             "replaces", "leave it unset"),
            ("stokes_wall_ghost", d.stokes_wall_ghost == "quadratic",
             "the pair sum's wall ghost; the strain-energy form builds its adjoint sums on "
             "Adami's mirror", "leave --wall-ghost at adami"),
            ("stokes_surface_rows", d.stokes_surface_rows == "traction",
             "the pair sum's free-surface rows; the strain-energy form holds the surface "
             "traction-free already", "leave --surface-rows at continuity"))
        for name, on, what, reset in pair_sum_only:
            if not on:
                continue
            named = f"run.dfsph.{name} = {getattr(d, name)!r} sets {what}"
            if not coupled:
                raise UserInputError(f"{named}; this run does not use the coupled solve: add "
                                     f"--creeping-solve coupled (and --scheme dfsph), or {reset}.")
            if d.stokes_surface_traction:
                raise UserInputError(f"{named}: turn run.dfsph.stokes_surface_traction off "
                                     f"(--no-surface-traction), or {reset}.")
        if d.stokes_inner_operator == "system":
            # the inner solve exists only in the coupled solve's block-triangular
            # preconditioner, and without the traction the system's block is the pair sum:
            # a setting that changes nothing is refused rather than recorded as if it had
            inert = [why for why, off in (
                ("the run does not use the coupled solve (--creeping-solve coupled, --scheme "
                 "dfsph)", not coupled),
                ("run.dfsph.stokes_preconditioner is 'block_diagonal', which has no inner "
                 "solve", d.stokes_preconditioner != "block_triangular"),
                ("run.dfsph.stokes_surface_traction is off, so the system's viscous block is "
                 "the pair sum already", not d.stokes_surface_traction)) if off]
            if inert:
                raise UserInputError(
                    "run.dfsph.stokes_inner_operator = 'system' changes nothing here: "
                    + "; ".join(inert) + ". Keep 'weiler2018', or change what is named.")


PAPER_PRESET = {
    "description": "The seed paper's PySPH baseline: EDAC, c_s = 6 m/s, eta = 0.1 Pa s, "
                   "nozzle one diameter above the plate, 60 mm/s (gcode/paper_*.gcode).",
    "scene": "print",
    "scene_options": {"gcode": "paper_bead.gcode", "nozzle_height": "one_diameter",
                      "nozzle_tip_outer_diameter_mm": None},
    "run": {"scheme": "edac", "edac": {"sound_speed_m_s": 6.0}},
    "material": {"viscosity_pa_s": 0.1, "viscosity_model": "newtonian"},
}

PRESETS = {"paper": PAPER_PRESET}

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
