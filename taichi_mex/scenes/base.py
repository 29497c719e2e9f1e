"""What every scene hands the simulation: particles, domain, times, physics it needs."""

from dataclasses import dataclass, field

import numpy as np


@dataclass
class ParticleBlock:
    """Particles to create at the start (absolute positions in m)."""

    position_m: np.ndarray
    phase: int
    velocity_m_s: np.ndarray | None = None
    temperature_c: np.ndarray | float | None = None
    bead: int = -1
    #: walls: the depth of each particle under the wall's surface (m) and the surface's unit
    #: normal into the melt, for a wall whose geometry gives them (a plane); None: not given
    wall_depth_m: np.ndarray | None = None
    wall_normal: tuple | None = None


@dataclass
class InletSpec:
    """A G-code-driven nozzle (see inlet.NozzleInlet)."""

    selection: object
    z_offset_m: float = 0.0
    tip_outer_diameter_m: float | None = None
    #: the nozzle's flank above its flat tip: its angle from the face's plane (deg; None: the
    #: flat tip alone) and how far above the face it reaches (m)
    flank_angle_deg: float | None = None
    body_height_m: float = 0.0


@dataclass
class CreepingScales:
    """What sets a print's creeping-flow numbers: the nozzle's speed, the nozzle bore, the
    run's duration (Reynolds number rho U L / eta, gravity number rho g L^2 / (eta U), slump
    rho g L T / eta)."""

    speed_m_s: float
    length_m: float
    duration_s: float


@dataclass
class ScenePlan:
    name: str
    domain_lo_m: np.ndarray
    domain_hi_m: np.ndarray
    t_start_s: float
    t_end_s: float
    #: the fastest motion the scene prescribes or releases (nozzle, plate, free fall), m/s:
    #: the blow-up speed limit and the time-step estimate follow from it
    speed_scale_m_s: float
    blocks: list[ParticleBlock] = field(default_factory=list)
    inlet: InletSpec | None = None
    #: fluid particles the inlet may add over the run (capacity planning)
    inflow_particles: int = 0
    #: physics the scene needs on top of the scheme ('thermal', ...)
    needs: set = field(default_factory=set)
    #: a point and the extrusion direction for cross-section snapshots (m, unit vector)
    section_point_m: np.ndarray | None = None
    section_direction: np.ndarray | None = None
    #: commanded deposition (m^3 as a function of time), for mass bookkeeping
    commanded_volume_m3: object = None
    #: the longest time step the scene's own sampling allows (s); None: the scheme's limit
    max_dt_s: float | None = None
    #: how far the fastest melt moves over the run (m), for scenes that know it (a slumping
    #: column): the implicit solver's CFL steps then number travel / (CFL x spacing), however
    #: fast the motion starts, beside the steps the longest step needs
    travel_m: float | None = None
    #: the walls' fastest speed (m/s) at an array of times (s), for scenes whose walls move
    #: on a known schedule (a print: the nozzle plus the melt sliding down its bore): the
    #: step estimate follows it through the run instead of taking its peak throughout
    wall_speed_m_s: object = None
    #: whether the walls feed melt at an array of times (s): a print's nozzle extrudes, or
    #: travels with its melt riding along, which the relative step lets take longer steps
    extruding: object = None
    #: heat's diffusion limit for scenes that know it up front (s)
    thermal_dt_s: float | None = None
    #: print scenes: the scales of the creeping-flow numbers (reported; idle spans)
    creeping: CreepingScales | None = None
    #: spans (t_from, t_to) in s in which nothing the scene prescribes touches the domain (the
    #: nozzle is outside it): a creeping melt may skip them (RunOptions.skip_idle)
    idle_windows: list = field(default_factory=list)
    #: a body force on the melt above a plane, ((ax, ay, az) in m/s^2, the plane's height z
    #: in m): a scene that drives its melt through a die by a pressure drop gives the drop as
    #: this force, which the pressure absorbs (the coupled solve reads it)
    drive: tuple | None = None
    #: what the scene reports about itself (copied into the summary; nothing reads it back)
    info: dict = field(default_factory=dict)

    @property
    def origin_m(self) -> np.ndarray:
        return 0.5 * (self.domain_lo_m + self.domain_hi_m)

    def initial_count(self, *phases: int) -> int:
        """Particles the scene starts with: all of them, or those of the given phases."""
        return int(sum(len(b.position_m) for b in self.blocks if not phases or b.phase in phases))


def box_walls(lo_m, hi_m, spacing_m: float, layers: int, open_top: bool = True) -> np.ndarray:
    """Wall particles around the box [lo, hi] (fluid inside), cell-centred lattice outside it."""
    lo = np.asarray(lo_m, dtype=np.float64)
    hi = np.asarray(hi_m, dtype=np.float64)
    n = np.round((hi - lo) / spacing_m).astype(int)
    ranges = [np.arange(-layers, n[k] + layers) for k in range(3)]
    if open_top:
        ranges[2] = np.arange(-layers, n[2] + 1)
    I, J, K = np.meshgrid(*ranges, indexing="ij")
    inside = (I >= 0) & (I < n[0]) & (J >= 0) & (J < n[1]) & (K >= 0)
    if not open_top:
        inside &= K < n[2]
    pts = np.stack([I[~inside], J[~inside], K[~inside]], axis=1)
    return lo + (pts + 0.5) * spacing_m


def lattice_block(lo_m, hi_m, spacing_m: float) -> np.ndarray:
    """Cell-centred cubic lattice filling [lo, hi]."""
    lo = np.asarray(lo_m, dtype=np.float64)
    hi = np.asarray(hi_m, dtype=np.float64)
    n = np.maximum(np.round((hi - lo) / spacing_m).astype(int), 1)
    axes = [lo[k] + (np.arange(n[k]) + 0.5) * spacing_m for k in range(3)]
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    return np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)


@dataclass
class Bore:
    """A vertical bore on the cell-centred lattice (the nozzle's bore, a die)."""

    melt: np.ndarray  # positions inside the circle of the radius asked for (m)
    wall: np.ndarray  # the lattice ring of the wall's layers outside it (m)
    spacing_m: float
    outer_m: float  # the wall's outer radius
    per_layer: int  # melt particles in one lattice layer

    @property
    def radius_m(self) -> float:
        """The melt's radius from its cross-section, sqrt(N dx^2 / pi) with N = per_layer (the
        wall's staircase moves it off the radius asked for)."""
        return float(np.sqrt(self.per_layer * self.spacing_m * self.spacing_m / np.pi))


def bore(radius_m: float, length_m: float, spacing_m: float, layers: int) -> Bore:
    """A bore from z = 0 to length_m: the lattice inside the circle of radius_m (melt) and the
    ring of ``layers`` spacings outside it (wall)."""
    outer = radius_m + layers * spacing_m
    box = lattice_block([-outer, -outer, 0.0], [outer, outer, length_m], spacing_m)
    r = np.hypot(box[:, 0], box[:, 1])
    melt = box[r < radius_m]
    layer = int(np.sum(np.abs(melt[:, 2] - melt[0, 2]) < 0.5 * spacing_m))
    return Bore(melt, box[(r >= radius_m) & (r < outer)], spacing_m, outer, layer)


@dataclass
class DiscFilm:
    """A melt film of gap h and radius R on the plate (z <= 0) under a disc of wall particles
    as wide (the film scenes: squeeze film, Couette film), in m; every wall's surface known."""

    melt: np.ndarray
    plate: np.ndarray
    disc: np.ndarray
    gap_m: float  #: h, a whole number of spacings
    disc_surface_m: float  #: the disc's surface: h, or above it where the disc is lifted
    reach_m: float  #: the plate's half-width
    pad_m: float  #: the domain's margin around the walls

    def blocks(self, disc_velocity_m_s) -> list:
        """The film, the plate and the disc (nozzle particles moving at disc_velocity)."""
        from taichi_mex.core.state import FLUID, NOZZLE, PLATE

        return [ParticleBlock(self.melt, FLUID),
                ParticleBlock(self.plate, PLATE, wall_depth_m=-self.plate[:, 2],
                              wall_normal=(0.0, 0.0, 1.0)),
                ParticleBlock(self.disc, NOZZLE,
                              velocity_m_s=np.tile(disc_velocity_m_s, (len(self.disc), 1)),
                              wall_depth_m=self.disc[:, 2] - self.disc_surface_m,
                              wall_normal=(0.0, 0.0, -1.0))]


def disc_film(radius_m: float, gap_m: float, run, scene: str, lift_m: float = 0.0) -> DiscFilm:
    """The film of ``scene`` at run's spacing, refusing a gap of a fraction of a spacing; the
    disc ``lift_m`` above the melt's top."""
    from taichi_mex.errors import UserInputError

    dx = run.spacing_m
    R, h = radius_m, gap_m
    if abs(h / dx - round(h / dx)) > 1e-6 or round(h / dx) < 2:
        raise UserInputError(f"The {scene}'s gap {h * 1e3:g} mm must hold a whole number (at "
                             f"least 2) of particle layers at {dx * 1e3:g} mm spacing; change "
                             "--gap-mm or --spacing-mm.")
    layers = run.wall_layers()
    melt = lattice_block([-R, -R, 0.0], [R, R, h], dx)
    melt = melt[np.hypot(melt[:, 0], melt[:, 1]) < R]
    reach = R + (layers + 1) * dx
    plate = lattice_block([-reach, -reach, -layers * dx], [reach, reach, 0.0], dx)
    disc = lattice_block([-R, -R, h], [R, R, h + layers * dx], dx)
    disc = disc[np.hypot(disc[:, 0], disc[:, 1]) < R]
    disc[:, 2] += lift_m
    return DiscFilm(melt, plate, disc, round(h / dx) * dx, h + lift_m, reach, (layers + 3) * dx)


def coupled_pla_defaults(spacing_mm: float, dfsph: dict | None = None, **run) -> dict:
    """Defaults of a scene measured by the coupled solve: PLA melt at 1000 Pa s (Newtonian),
    DFSPH with the coupled creeping solve at ``spacing_mm``; ``dfsph``: further DFSPH options,
    ``run``: further run options."""
    return {"run": {"scheme": "dfsph", "spacing_mm": spacing_mm, **run,
                    "dfsph": {"creeping_solve": "coupled", **(dfsph or {})}},
            "material": {"name": "PLA melt", "density_kg_m3": 1240.0, "viscosity_pa_s": 1000.0,
                         "viscosity_model": "newtonian"}}


def require_coupled_solve(run, scene: str) -> None:
    """Scenes measured by one coupled viscous-pressure solve refuse other solvers up front."""
    from taichi_mex.errors import UserInputError

    if run.scheme != "dfsph" or run.dfsph.creeping_solve != "coupled":
        raise UserInputError(f"The {scene} is measured by one coupled viscous-pressure solve: "
                             "run it with --scheme dfsph --creeping-solve coupled (its default).")
