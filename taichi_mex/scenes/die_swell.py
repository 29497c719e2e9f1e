"""Extrudate swell: creeping melt pushed out of a long round die into free space. A Newtonian
jet leaving a tube at zero Reynolds number, without gravity or surface tension, swells to
D_jet / D = 1.13 within about a diameter of the exit (Nickell, Tanner & Caswell, J. Fluid
Mech. 65, 1974; Tanner, Engineering Rheology, 2nd ed., 2000, Sec. 9.6): the Poiseuille
profile relaxes to a plug, the slow melt at the wall speeds up, the fast core slows down, and
the free surface moves out until it is a streamline of the plug. It tests what a strand needs
where it leaves the nozzle and no other case checks: a traction-free surface whose shape is
set by a velocity profile rearranging under it.

The die is the nozzle's bore (radius 0.2 mm, no-slip wall of the run's wall layers), exit
plane at z = 0, melt column open at the top; the jet hangs below, open at its end. The melt is
driven by a body force a = 8 nu U / R^2 on the melt above the exit plane: Poiseuille's profile
of mean speed U in the die. The force is -grad(phi) with phi = -a z above the plane and 0
below, continuous, so the pressure absorbs it (p + rho phi): in the jet, where phi = 0, that
is the pressure, and the problem is the pressure-driven die's.

The steady free surface is found as Nickell, Tanner & Caswell found theirs: solve the Stokes
flow in a trial geometry (one coupled solve, nothing moved), move the jet's surface to the
streamline that leaves the die's lip, R(z) = R + integral of u_r / u_z along the surface,
rebuild the jet on that profile and repeat. (Stepping the melt out of the die in time instead
stalled the coupled solve within two radii of travel at whatever drove it, a piston's corner
or a draining column top, before the jet settled.)

The jet is rebuilt from the die's lattice, the points inside R(z), so it can take only the
shapes the lattice's rings allow: at 4 particles per radius the squared radii of the
cell-centred lattice's points lie 2 dx^2 apart, so near a swell of 1.14 the surface moves in
steps of 0.22 dx, 5 % of R. The map from a trial geometry to its streamline's geometry is
then a map between finitely many particle sets, and the iteration ends where it must: when
the set it would build next is one it has solved already. A set that rebuilds itself is a
fixed point; otherwise the sets since its first solve are a cycle, the surface lies between
them (measured at 4 per radius: two sets 24 particles apart in turn, whose streamlines read
1.143 and 1.154), and the swell is the mean of the cycle's readings with their spread as its
resolution. On finer lattices the sets along the whole jet rarely recur exactly; where none
has within the solves allowed, the swell is the mean over every rebuilt geometry and the
spread that of their readings, and the surface is reported unsettled. No tolerance stands
in for that: a test on the swell's change finer than a ring step cannot be met, and one
coarser would stop on whichever set came first.
The swell is the streamline's far radius over R, with two checks: the jet's cross-section in
particles over the die's (the lattice's own reading of the geometry, in ring steps), and
sqrt(U_die / u_jet) from the mean axial speeds (continuity; equal to the swell when the
surface is a streamline and nothing crosses it).
"""

import math
from dataclasses import asdict, dataclass

import numpy as np

from taichi_mex.core.state import FLUID, NOZZLE
from taichi_mex.errors import UserInputError
from taichi_mex.options import Positive, Range, opt
from taichi_mex.scenes.base import (ParticleBlock, ScenePlan, bore, coupled_pla_defaults,
                                    lattice_block, require_coupled_solve)
from taichi_mex.scenes.registry import SceneEntry, register

#: Nickell, Tanner & Caswell (1974): a Newtonian creeping jet from a long round tube
NEWTONIAN_SWELL = 1.13


class DieSwellScene:
    name = "die-swell"

    def __init__(self, radius_mm: float = 0.2, die_radii: float = 8.0, jet_radii: float = 10.0,
                 iterations: int = 8):
        self.options = DieSwellOptions(radius_mm, die_radii, jet_radii, iterations)
        self.R = radius_mm * 1e-3
        self.L_die = die_radii * self.R
        self.L_jet = jet_radii * self.R
        self.iterations = int(iterations)
        #: the jet's radius against depth below the exit (m -> m); None: straight, R
        self.jet_profile = None
        self.U = 0.01  # m/s: the die's mean speed; a creeping flow's shape does not depend on it

    def plan(self, run, material) -> ScenePlan:
        require_coupled_solve(run, "die swell")
        dx = run.spacing_m
        layers = run.wall_layers()
        b = bore(self.R, self.L_die, dx, layers)
        die, wall, radius, outer = b.melt, b.wall, b.radius_m, b.outer_m
        # the jet on the die's lattice (same offsets across, layers at -(k + 1/2) dx), wide
        # enough for a swell of 2
        wide = outer + math.ceil((2.0 * self.R - outer) / dx) * dx if 2.0 * self.R > outer else outer
        layers_down = math.ceil(self.L_jet / dx - 1e-9)
        self.lattice = lattice_block([-wide, -wide, -layers_down * dx], [wide, wide, 0.0], dx)
        jet = self.lattice[self._inside(self.jet_profile)]
        # capacity for the jet's later geometries (analyse rebuilds it in place): a swell of 2
        room = int(3 * np.sum(np.hypot(jet[:, 0], jet[:, 1]) < self.R))
        self.dx = dx
        self.layer = b.per_layer  # the lattice's reading of the swell counts against it
        nu = material.viscosity_pa_s / material.density_kg_m3
        pad = (layers + 3) * dx
        side = wide + pad  # wide >= outer
        return ScenePlan(
            name=self.name,
            domain_lo_m=np.array([-side, -side, -self.L_jet - pad]),
            domain_hi_m=np.array([side, side, self.L_die + pad]),
            t_start_s=0.0, t_end_s=0.0,
            blocks=[ParticleBlock(np.concatenate([jet, die]), FLUID), ParticleBlock(wall, NOZZLE)],
            section_point_m=np.zeros(3), section_direction=np.array([0.0, 1.0, 0.0]),
            speed_scale_m_s=2.0 * self.U,
            inflow_particles=room,
            drive=((0.0, 0.0, -8.0 * nu * self.U / radius**2), 0.0),
            info={"radius_m": self.R, "die_length_m": self.L_die, "jet_length_m": self.L_jet},
        )

    def _inside(self, profile) -> np.ndarray:
        """Which of the jet's lattice points lie inside a profile (None: straight, R): the
        geometry a profile builds, and what tells two geometries apart."""
        x = self.lattice
        rj = profile(-x[:, 2]) if profile is not None else self.R
        return np.hypot(x[:, 0], x[:, 1]) < rj

    # ------------------------------------------------------------ measurement
    def _measure(self, sim) -> dict:
        """One coupled solve in the present geometry; the surface streamline from the lip."""
        res = sim.solver.quasi_static()
        x = sim.state.numpy("position", FLUID)
        v = sim.state.numpy("velocity", FLUID)
        R, dx = self.R, self.dx
        r = np.hypot(x[:, 0], x[:, 1])
        z = x[:, 2]
        ur = (x[:, 0] * v[:, 0] + x[:, 1] * v[:, 1]) / np.maximum(r, 1e-30)
        uz = -v[:, 2]
        in_die = (z > 0.25 * self.L_die) & (z < 0.75 * self.L_die)
        depth, slope, count, speed = [], [], [], []
        for k in range(int(round(self.L_jet / dx))):
            s = (z < -k * dx) & (z >= -(k + 1) * dx)
            if not s.any():
                break
            # the surface: the slab's outermost ring of particles
            surface = s & (r > r[s].max() - 0.3 * dx)
            depth.append((k + 1) * dx)  # the slab's bottom: the rise below sums its slope
            slope.append(float(np.mean(ur[surface]) / np.mean(uz[surface])))
            count.append(int(s.sum()))
            speed.append(float(np.mean(uz[s])))
        # from the lip (depth 0, rise 0) down
        depth = np.concatenate([[0.0], depth])
        rise = np.concatenate([[0.0], np.cumsum(np.array(slope) * dx)])
        mid = depth[1:] - 0.5 * dx
        far = (mid > 4.0 * R) & (mid < 6.0 * R)
        if not far.any():
            raise UserInputError("The die-swell jet is too short to read its swell 4-6 radii "
                                 "below the exit: raise jet_radii.")
        u_die = float(np.mean(uz[in_die]))
        u_jet = float(np.mean(np.array(speed)[far]))
        return {"streamline": 1.0 + float(np.mean(rise[1:][far])) / R,
                "lattice": math.sqrt(float(np.mean(np.array(count)[far])) / self.layer),
                "kinematic": math.sqrt(u_die / u_jet), "u_die": u_die, "u_jet": u_jet,
                "depth": depth, "rise": rise, "iterations": res.iterations,
                "converged": bool(res.converged)}

    def analyse(self, sim) -> dict:
        """Nickell, Tanner & Caswell's iteration on the lattice: solve, move the surface to the
        lip's streamline, rebuild, until the geometry to build is one already solved (a fixed
        point, or a cycle the surface lies within: the module's docstring)."""
        history, solved = [], []  # each geometry's measurement, and its lattice points
        profile = None  # straight, R
        cycle = None  # the index of the first geometry of the cycle found
        try:
            for k in range(self.iterations):
                inside = self._inside(profile)
                cycle = _index_of(solved, inside)
                if cycle is not None:
                    break
                if k:
                    # the particles of the new jet in place of the old (room for a swell of 2)
                    self.jet_profile = profile
                    sim.place(self.plan(sim.run_opts, sim.material).blocks, replace=True)
                solved.append(inside)
                m = self._measure(sim)
                history.append(m)
                profile = (lambda d, depth=m["depth"], rise=m["rise"]:
                           self.R + np.interp(d, depth, rise))
            else:
                # the last solve's streamline may rebuild a geometry solved already
                cycle = _index_of(solved, self._inside(profile))
        finally:
            self.jet_profile = None
        last = history[-1]
        # the swell's readings: over the cycle where the iteration closed one, else over every
        # rebuilt geometry (the straight start is no trial of the surface), their spread the
        # iteration's own scatter
        over = history[cycle:] if cycle is not None else (history[1:] or history)
        mean = lambda key: float(np.mean([h[key] for h in over]))  # noqa: E731
        swell = mean("streamline")
        return {"swell": swell, "swell_lattice": mean("lattice"),
                "swell_kinematic": mean("kinematic"), "swell_reference": NEWTONIAN_SWELL,
                "swell_error": swell / NEWTONIAN_SWELL - 1.0,
                "swell_spread": float(np.ptp([h["streamline"] for h in over])),
                "swell_history": [h["streamline"] for h in history],
                "swell_kinematic_history": [h["kinematic"] for h in history],
                "swell_lattice_history": [h["lattice"] for h in history],
                "jet_particles_each": [int(s.sum()) for s in solved],
                "surface_converged": cycle is not None,
                "surface_cycle": len(history) - cycle if cycle is not None else 0,
                "surface_depth_m": last["depth"].tolist(),
                "surface_radius_ratio": (1.0 + last["rise"] / self.R).tolist(),
                "die_mean_speed_m_s": last["u_die"], "jet_speed_m_s": last["u_jet"],
                "geometry_iterations": len(history),
                "stokes_iterations_each": [h["iterations"] for h in history],
                "stokes_converged": all(h["converged"] for h in history),
                "radius_m": self.R}


def _index_of(solved: list, inside: np.ndarray) -> int | None:
    """Where a geometry (its lattice points) is among those solved, or None."""
    return next((i for i, s in enumerate(solved) if np.array_equal(s, inside)), None)


@dataclass
class DieSwellOptions:
    radius_mm: float = opt(0.2, help="die (bore) radius R (mm)", check=Positive(), flag="--radius-mm")
    die_radii: float = opt(8.0, help="length of the melt column in the die, in radii (-)",
                           check=Range(4.0, 100.0))
    jet_radii: float = opt(10.0, help="length of the jet below the exit, in radii (-; the "
                           "swell is read 4-6 radii down)", check=Range(8.0, 100.0))
    iterations: int = opt(8, help="most solves of the free-surface iteration (-; it ends "
                          "sooner where the geometry to build next was solved already)",
                          check=Range(1, 100, integer=True), flag="--surface-iterations")


def _defaults(_options) -> dict:
    # the free surface as prints run it: the pair sum, no surface traction
    return coupled_pla_defaults(0.05, {"stokes_surface_traction": False}, gravity_m_s2=0.0)


register(SceneEntry("die-swell", "creeping melt pushed out of a round die (extrudate swell)",
                    DieSwellOptions, lambda o: DieSwellScene(**asdict(o)), _defaults))
