"""The run loop: build a scene's Taichi state, step it, write frames, report.

    from taichi_mex import Simulation, RunOptions
    from taichi_mex.scenes.print import PrintScene

    sim = Simulation(PrintScene("print.gcode"), RunOptions(spacing_mm=0.05), out_dir="run")
    summary = sim.run()
    xyz = sim.state.numpy("position", phase=0)   # fluid particles, metres
"""

import json
import logging
import os
import time
from pathlib import Path

import numpy as np

from taichi_mex import backend
from taichi_mex.options import RESOLUTION_PRESETS, Material, RunOptions, to_dict
from taichi_mex.errors import SimulationDiverged, UserInputError
from taichi_mex.core.state import FLUID, NOZZLE, PHASE_NAMES, PLATE, SOLID, shape_bucket

log = logging.getLogger("taichi_mex")

#: bytes per particle besides the registered fields: neighbour lists, sort buffers
_TEMP_FACTOR = 2.0

#: particle-steps per second measured on a 2-core CPU (validation/trade and windows;
#: the DFSPH figure is the single bead at standard resolution, the EDAC one the
#: 100k-particle block); the wall-time estimate scales them with the thread count.
#: The coupled creeping solve's figures are *melt* particle-steps per second: its cost is in
#: its melt rows, the walls around them cost next to nothing (the bundled bead, 17,616
#: particles of which 1,376 melt at the end, costs per melt particle-step what the paper block
#: costs with 10,945 of 36,897). Counting every particle put the unscaled paper block at
#: 4 min where it took 19 (2026-12-06).
#: dfsph-coupled: melt particle-steps, start-up left out, at draft's spacing (see
#: COUPLED_RATE_*), alone on 2 cores, 2026-12-05/06: the bundled bead 35,000-38,000, benchy's
#: 4 x 4 mm window 31,900, the unscaled paper block 29,900;
#: dfsph-coupled-traction: the same solve with the free surface's traction, about nine times
#: the cost per melt particle-step (the 4 mm collapse at 10 Pa s, its steps set by its
#: motion: 4,100 at 0.5 mm, 2026-12-06; 3,200 at 0.3 mm, 2026-12-05)
MEASURED_RATE_2CORE = {"edac": 1.3e6, "dfsph": 2.6e5, "dfsph-coupled": 3.2e4,
                       "dfsph-coupled-traction": 3.5e3, "static": 3.0e6}
#: a print's coupled solve takes more iterations a step the finer its spacing (the bundled
#: bead at 3 / 4 / 6 particles per 0.2 mm gap: 9 / 10 / 12 GMRES and 47 / 54 / 93 inner
#: iterations a step, validation/trade 2026-12-04): its rate holds at draft's spacing and
#: falls as (draft spacing / spacing)^0.6 below it (the bundled bead, melt particle-steps a
#: second, start-up left out, alone, 2026-12-06: draft 35,000, standard 23,300, fine 25,700;
#: the power's least-squares fit through draft); coarser spacings keep draft's rate (not
#: measured, and not extrapolated)
COUPLED_RATE_SPACING_M = RESOLUTION_PRESETS["draft"]["run"]["spacing_mm"] * 1e-3
COUPLED_RATE_EXPONENT = 0.6
#: kernel compilation and set-up before the first step (s), from the same runs
STARTUP_S = 10.0
#: measured wall time / estimate: the DFSPH rate is an older single-bead rate (the default
#: bead ran 3.5x faster, the paper blocks at 1.0-1.1x its time); the coupled solve, counting
#: melt particle-steps: the bundled bead at draft / standard / fine 0.95 / 1.15 / 0.78x,
#: benchy's 4 x 4 mm window 0.86-1.03x, the unscaled paper block 1.07-1.17x, block_3x3
#: 1.06-1.13x (alone, 2026-12-06); with
#: the surface traction, earlier runs at 1.3-1.5x and the collapse, its steps set by its
#: motion, at 0.4-1.1x (0.3 to 0.5 mm, 2026-12-05/06)
ESTIMATE_SPREAD = {"dfsph": (0.3, 1.1), "dfsph-coupled": (0.75, 1.2),
                   "dfsph-coupled-traction": (0.4, 1.5)}


def available_memory_bytes() -> int:
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES"))


class Simulation:
    @classmethod
    def from_spec(cls, spec, out_dir=None, scene=None) -> "Simulation":
        """The run a :class:`~taichi_mex.spec.RunSpec` describes (the way every entry point
        builds one). scene: the spec's scene if already built (a print's plan then is not
        made twice)."""
        spec.validate()
        return cls(scene if scene is not None else spec.build_scene(), spec.run, spec.material,
                   out_dir=out_dir, preset=spec.preset, material_source=spec.material_source)

    def __init__(self, scene, run: RunOptions | None = None, material: Material | None = None,
                 out_dir=None, preset: str | None = None, material_source: str | None = None):
        # provenance of the run description (config.json): what the options started from
        self.preset = preset
        self.material_source = material_source
        self.run_opts = run or RunOptions()
        self.material = material or Material()
        self.run_opts.validate()
        self.material.validate()
        self.scene = scene
        self.plan = scene.plan(self.run_opts, self.material)
        self.creeping = self._creeping_numbers()
        self.viscosity_scale = self.creeping["viscosity_scale"]
        self._check_split_solve()
        self._check_probes()
        if self.run_opts.snapshot_field == "temperature" and not (
                self.run_opts.thermal.enabled or "thermal" in self.plan.needs):
            raise UserInputError("Pictures coloured by temperature need heat: add --thermal (or "
                                 "colour by density, pressure, velocity, bead_id or phase).")
        self.probes = None
        self.out_dir = Path(out_dir) if out_dir else None
        self._pairing = None
        self.estimate = self._estimate()
        if self.estimate["memory_bytes"] > 0.8 * available_memory_bytes():
            raise UserInputError(
                f"This scene needs about {self.estimate['memory_bytes'] / 2**30:.1f} GiB for "
                f"{self.estimate['particles']:,} particles, more than the "
                f"{available_memory_bytes() / 2**30:.1f} GiB available. Use a coarser "
                "--resolution, fewer --layers or a smaller --region.")
        if self.estimate["steps_estimate"] > self.run_opts.max_steps:
            limits = self.estimate["dt_limits_s"]
            worst = min(limits, key=limits.get)
            advice = ("the implicit solver (--scheme dfsph) has no viscous limit" if worst == "viscous"
                      else "use a coarser --resolution or a shorter --until")
            raise UserInputError(
                f"This run would need about {self.estimate['steps_estimate']:,} time steps: the "
                f"{worst} limit holds dt at {limits[worst]:.3g} s over "
                f"{self.estimate['simulated_time_s']:.3g} s, more than the run's limit of "
                f"{self.run_opts.max_steps:,} steps (RunOptions.max_steps); {advice}, or raise "
                "the limit.")
        self._built = False
        self.skipped: list[dict] = []
        self.lost_particles = 0
        self.lost_by_face: dict[str, int] = {}
        self.lost_times_s: list[float] = []  # first and last time melt was lost
        # melt outside the domain's box (kept: core/grid.py, cell_coords): the most at once,
        # the most beyond each face, and the first and last time any was
        self.outside_max = 0
        self.outside_by_face: dict[str, int] = {}
        self.outside_times_s: list[float] = []
        self.over_face = _over_face_record()
        self.resumed = False
        self._description = None
        self.time_s = self.plan.t_start_s
        self.steps = 0
        self.history: list[dict] = []

    # ----------------------------------------------------------------- planning
    def _check_split_solve(self) -> None:
        """The split solve (DFSPH as its papers give it) is for inertial flows: where the
        melt's steps may be creeping, splitting viscosity from pressure leaves an error the
        size of the solution (physics/stokes.py), so such a run is refused before it starts."""
        run = self.run_opts
        if run.scheme != "dfsph" or run.dfsph.creeping_solve != "split":
            return
        m = self.material
        nu = m.viscosity_pa_s * self.viscosity_scale / m.density_kg_m3
        dt = self.plan.max_dt_s or run.dfsph.max_dt_s
        ratio = nu * dt / run.spacing_m**2
        if ratio >= run.dfsph.creeping_diffusion:
            raise UserInputError(
                f"The split solve is for inertial flows, and this melt creeps: at "
                f"{m.viscosity_pa_s * self.viscosity_scale:.3g} Pa s its steps of up to "
                f"{dt:.3g} s reach nu dt / dx^2 = {ratio:.3g}, over run.dfsph.creeping_diffusion "
                f"= {run.dfsph.creeping_diffusion:g}, where solving viscosity before pressure "
                "leaves an error the size of the solution. Use --creeping-solve coupled (the "
                "default).")

    def _check_probes(self) -> None:
        lo, hi = self.plan.domain_lo_m * 1e3, self.plan.domain_hi_m * 1e3
        for point in self.run_opts.probes_mm:
            if np.any(np.asarray(point) < lo) or np.any(np.asarray(point) > hi):
                raise UserInputError(
                    f"Probe ({point[0]:g}, {point[1]:g}, {point[2]:g}) mm lies outside the simulated "
                    f"domain x {lo[0]:.3g}..{hi[0]:.3g}, y {lo[1]:.3g}..{hi[1]:.3g}, z "
                    f"{lo[2]:.3g}..{hi[2]:.3g} mm; move it inside (the plan shows the selection).")

    def _creeping_numbers(self) -> dict:
        """Reynolds number Re = rho U L / eta, gravity number G = rho g L^2 / (eta U) and the
        gravity slump over the run S = rho g L T / eta (strain a layer of thickness L would
        creep under its own weight in time T), at the real viscosity and as run (times
        1 / viscosity_scale: all three fall as 1 / eta)."""
        scales = self.plan.creeping
        scale = float(self.run_opts.viscosity_scale)
        eta = self.material.zero_shear_viscosity(self.material.extrusion_temperature_c)
        rho, g = self.material.density_kg_m3, self.run_opts.gravity_m_s2
        if scales is None or eta <= 0:
            return {"viscosity_scale": scale}
        U, L, T = scales.speed_m_s, scales.length_m, scales.duration_s
        raw = {"reynolds": rho * U * L / eta, "gravity_number": rho * g * L * L / (eta * U),
               "gravity_slump": rho * g * L * T / eta}
        out = {"viscosity_scale": scale, "viscosity_as_run_pa_s": eta * scale}
        for key, value in raw.items():
            out[f"{key}_unscaled"] = value
            out[key] = value / scale
        return out

    def describe_creeping(self) -> str | None:
        c = self.creeping
        if "reynolds" not in c:
            return None
        head = ("creeping-flow scaling: viscosity x {:.3g} -> {:.4g} Pa s".format(
            c["viscosity_scale"], c["viscosity_as_run_pa_s"]) if c["viscosity_scale"] < 1
            else "real viscosity (no creeping-flow scaling)")
        return (f"{head}; Reynolds {c['reynolds']:.2g}, gravity number {c['gravity_number']:.2g}, "
                f"gravity slump over the run {c['gravity_slump']:.2g} (unscaled: "
                f"{c['reynolds_unscaled']:.2g}, {c['gravity_number_unscaled']:.2g}, "
                f"{c['gravity_slump_unscaled']:.2g})")

    def _estimate(self) -> dict:
        run = self.run_opts
        dx = run.spacing_m
        kernel, factor = run.resolved_kernel()
        H = factor * dx
        initial = self.plan.initial_count()
        inflow = self.plan.inflow_particles
        inlet_extra = 0
        if self.plan.inlet is not None:
            inlet_extra = 4 * int(np.pi * (0.5e-3 * self.plan.inlet.selection.trajectory.printer.nozzle_diameter_mm / dx + 1) ** 2) * int(factor + 2)
            spec = self.plan.inlet
            if spec.tip_outer_diameter_m:
                from taichi_mex.sim.boundaries import column_slices, nozzle_tip_lattice

                # the tip the inlet will build (NozzleInlet._tip_offsets)
                bore_r = 0.5e-3 * spec.selection.trajectory.printer.nozzle_diameter_mm
                inlet_extra += len(nozzle_tip_lattice(
                    bore_r, 0.5 * spec.tip_outer_diameter_m, dx, column_slices(H, dx),
                    spec.flank_angle_deg, spec.body_height_m))
        capacity = shape_bucket(int(1.02 * (initial + inflow + inlet_extra)) + 64)
        # only the inlet turns particles into melt: plate, nozzle and solid never melt, so the
        # rest bounds the melt rows of the coupled solve, whose Krylov vectors are stored by row
        walls = self.plan.initial_count(PLATE, NOZZLE, SOLID)
        melt_capacity = shape_bucket(max(capacity - walls, 64))
        ext = self.plan.domain_hi_m - self.plan.domain_lo_m
        n_cells = int(np.prod(np.ceil(2 * ext / H)))  # cells of half the support radius
        fp = 8 if run.precision == "f64" else 4
        # ~40 scalar fields across core, scheme and sort buffers, plus neighbour lists
        from taichi_mex.sim.solver import SOLVERS

        skin = run.edac.list_skin if run.scheme == "edac" else 0.0  # fraction of the support
        max_nbr = self._max_neighbours(factor * (1.0 + skin))
        cached = getattr(SOLVERS[run.scheme], "cached_per_neighbour", 0)  # reals per list slot
        per_particle = int(_TEMP_FACTOR * 40 * fp + (4 + cached * fp) * max_nbr)
        per_melt = 0  # bytes per melt row: the coupled solve's Krylov vectors
        if run.scheme == "dfsph" and run.dfsph.creeping_solve == "coupled":
            # physics/stokes.py, in f64: per melt row the Krylov basis (restart + 1 4-vectors)
            # and the flexible GMRES's preconditioned vectors (restart); per particle and list
            # slot the viscous coefficient (f64), the inner solve's (f32) and V F (the state's
            # precision), about 20 vectors and matrices of scratch (680 bytes), and the
            # extrapolated initial guess's previous velocities
            m = run.dfsph.stokes_restart
            # GMRES's inner product: T of each basis vector and of w
            weights = (m + 2) * 32 if run.dfsph.stokes_norm == "criterion" else 0
            inner = 4 if run.dfsph.stokes_preconditioner == "block_triangular" else 0
            per_particle += (8 + inner + fp) * max_nbr + 680
            per_melt = (2 * m + 1) * 32 + weights
            if weights and inner:
                per_melt += 96  # B and dt G(k) by row for the inner right-hand side
            if run.dfsph.stokes_initial_guess == "extrapolated":
                per_particle += 3 * fp
        memory = capacity * per_particle + melt_capacity * per_melt + 8 * n_cells
        span = max(self.plan.t_end_s - self.plan.t_start_s, 0.0)
        idle = sum(b - a for a, b in self.plan.idle_windows) if self.run_opts.skip_idle else 0.0
        dt, limits = self._dt_guess(H)
        dt *= run.dt_factor  # the run multiplies every limit by it
        steps = int(np.ceil((span - idle) / dt)) if dt > 0 else 0
        initial_melt = self.plan.initial_count(FLUID)
        # the melt grows with the deposition; without a commanded volume, linearly
        melt_steps = steps * (initial_melt + 0.5 * inflow)
        if self.plan.wall_speed_m_s is not None and run.scheme == "dfsph" and span > idle:
            steps, melt_steps = self._steps_along_the_walls(limits, initial_melt, H)
            dt = (span - idle) / max(steps, 1)
        if self.plan.travel_m is not None and run.scheme == "dfsph":
            # the CFL step follows the melt's speed, which decays as a slump creeps: count the
            # steps that cover the travel at the CFL step plus those the longest step needs
            # (an upper bound on sum(max(v dt / (cfl dx), dt / max_dt)) over the run)
            by_travel = int(np.ceil((self.plan.travel_m / (run.dfsph.cfl * 0.4 * dx)
                                     + (span - idle) / limits["max"]) / run.dt_factor))
            if by_travel < steps:
                melt_steps *= by_travel / steps
                steps, dt = by_travel, (span - idle) / by_travel
        warn = []
        if "viscous" in limits and limits["viscous"] < 0.1 * limits["cfl"]:
            warn.append(
                f"Explicit viscosity (eta = {self.material.viscosity_pa_s:g} Pa s) limits the time "
                f"step to {limits['viscous']:.3g} s, {limits['cfl'] / limits['viscous']:.0f}x below "
                "the CFL limit; the implicit solver (--scheme dfsph) removes this limit.")
        return {"warnings": warn, "dt_limits_s": limits, "particles": initial + inflow, "capacity": capacity,
                "melt_capacity": melt_capacity, "grid_cells": n_cells,
                "memory_bytes": memory, "simulated_time_s": span, "dt_estimate_s": dt,
                "list_skin": skin,
                "idle_s": idle,
                "steps_estimate": steps,
                "melt_particle_steps_estimate": float(melt_steps),
                "wall_time_estimate_s": self._wall_estimate(initial, inflow, steps, melt_steps),
                "kernel": kernel, "support_radius_m": H, "max_neighbours": max_nbr}

    def _steps_along_the_walls(self, limits: dict, initial_melt: int,
                               H: float) -> tuple[int, float]:
        """Steps of the solver's CFL rule on the walls' speed as it goes (a print: the nozzle
        speeds up, slows down and travels; its peak held throughout counted benchy's 4 x 4 mm
        window at 14,090 steps, which took 7,864-8,452), summed over the spans the run does
        not skip, on samples 0.1 ms apart (at most a million: coarser over a long print); and
        the melt particle-steps over them, the melt being what the scene starts with and the
        commanded volume deposited by then. With the relative step, a travel's melt rides with
        the nozzle and only the time to contact bounds it: (H / 2 + f cfl 0.4 dx) / speed
        (DFSPHSolver.time_step); an extrusion's melt shears against the bead below at no more
        than the nozzle's speed, which counts 1.2-1.4x the steps measured (tests/test_idle.py)."""
        run = self.run_opts
        t0, t1 = self.plan.t_start_s, self.plan.t_end_s
        n = int(min(max(np.ceil((t1 - t0) / 1e-4), 1000), 1_000_000))
        h = (t1 - t0) / n
        times = t0 + (np.arange(n) + 0.5) * h
        keep = np.ones(n, dtype=bool)
        if run.skip_idle:
            for a, b in self.plan.idle_windows:
                keep &= ~((times >= a) & (times < b))
        speed = np.maximum(self.plan.wall_speed_m_s(times[keep]), 1e-9)
        cfl = run.dfsph.cfl * 0.4 * run.spacing_m / speed
        if (self.plan.extruding is not None and run.dfsph.time_step_speed == "relative"
                and run.dfsph.creeping_solve == "coupled"):
            riding = ~self.plan.extruding(times[keep])
            cfl = np.where(riding, cfl + 0.5 * H / run.dt_factor / speed, cfl)
        per_sample = h / (np.minimum(cfl, limits.get("max", np.inf)) * run.dt_factor)
        melt = np.full(per_sample.shape, float(initial_melt))
        if self.plan.commanded_volume_m3 is not None:
            # the commanded volume on a coarse grid (a call each), in particles
            coarse = np.linspace(t0, t1, 401)
            volume = np.array([self.plan.commanded_volume_m3(t) for t in coarse])
            melt += np.interp(times[keep], coarse, volume) / run.spacing_m**3
        return int(np.ceil(np.sum(per_sample))), float(np.sum(per_sample * melt))

    def _wall_estimate(self, initial: int, inflow: int, steps: float,
                       melt_steps: float) -> float | None:
        """Wall time (s) from the measured rates: the melt grows linearly during deposition,
        so a run costs about (initial + inflow / 2) particles x steps; the coupled solve's cost
        is in its melt rows, so it counts the melt particle-steps alone. None on a GPU (not
        measured)."""
        run = self.run_opts
        key = self._rate_key()
        if run.arch != "cpu" or key not in MEASURED_RATE_2CORE:
            return None
        rate = MEASURED_RATE_2CORE[key]
        if key.startswith("dfsph-coupled"):
            # not scaled with the threads: the 2-core rate is partly one thread's (the solve's
            # loops stay on the calling thread below stokes' serial_pair_rows, 4,096 melt rows,
            # and its streams below serial_rows), and how its loops scale on more cores has
            # not been measured; an estimate that assumed they did could promise a many-core
            # user a fraction of the time
            if key == "dfsph-coupled":
                rate *= min(run.spacing_m / COUPLED_RATE_SPACING_M, 1.0) ** COUPLED_RATE_EXPONENT
            return STARTUP_S + melt_steps / rate
        threads = run.cpu_threads or os.cpu_count() or 2
        rate *= min(threads, os.cpu_count() or threads) / 2.0
        return STARTUP_S + (initial + 0.5 * inflow) * steps / rate

    def _rate_key(self) -> str:
        """The measured rate that applies: the coupled creeping solve has its own (with the
        surface traction several times the split one's per particle-step)."""
        run = self.run_opts
        if run.scheme == "dfsph" and run.dfsph.creeping_solve == "coupled":
            return "dfsph-coupled-traction" if run.dfsph.stokes_surface_traction else "dfsph-coupled"
        return run.scheme

    @staticmethod
    def _max_neighbours(factor: float) -> int:
        nominal = 4.0 / 3.0 * np.pi * factor**3
        return int(np.ceil(2.5 * nominal / 8.0) * 8)

    def _dt_guess(self, H: float) -> tuple[float, dict]:
        """Expected time step and its limits (s), from the scene's speed scale."""
        run = self.run_opts
        v = self.plan.speed_scale_m_s
        scale = self.viscosity_scale
        nu = self.material.zero_shear_viscosity(self.material.extrusion_temperature_c) * scale \
            / self.material.density_kg_m3
        if run.scheme == "edac":
            h = 0.5 * H
            limits = {"cfl": run.edac.cfl * h / (run.edac.sound_speed_m_s + v)}
            if nu > 0:
                limits["viscous"] = 0.125 * h * h / nu
        elif run.scheme == "static":
            limits = {"max": self.plan.max_dt_s or 1.0}
            if self.plan.thermal_dt_s is not None:
                limits["thermal"] = self.plan.thermal_dt_s
        else:
            # the same bounds as the solver's time_step: CFL on the scene's speed, and the
            # scene's own largest step where it sets one (slow creeping scenes), else the option's
            limits = {"cfl": run.dfsph.cfl * 0.4 * run.spacing_m / max(v, 1e-9),
                      "max": self.plan.max_dt_s or run.dfsph.max_dt_s}
        return min(limits.values()), limits

    def describe_estimate(self) -> str:
        e = self.estimate
        return (f"{e['particles']:,} particles (capacity {e['capacity']:,}), about "
                f"{e['memory_bytes'] / 2**20:.0f} MiB, {e['grid_cells']:,} grid cells; "
                f"{e['simulated_time_s']:.4g} s simulated"
                + (f" ({e['idle_s']:.3g} s of it with the nozzle away: heat only, or skipped)"
                   if e.get("idle_s") else "")
                + f" in about {e['steps_estimate']:,} steps "
                f"of {e['dt_estimate_s']:.3g} s" + self._describe_wall(e.get("wall_time_estimate_s")))

    def _describe_wall(self, wall) -> str:
        if wall is None:
            return "; no measured rate for this architecture, so no wall-time estimate"
        threads = self.run_opts.cpu_threads or os.cpu_count()
        text = f"{wall:.0f} s" if wall < 120 else (f"{wall / 60:.0f} min" if wall < 7200 else f"{wall / 3600:.1f} h")
        spread = ""
        key = self._rate_key()
        if key in ESTIMATE_SPREAD:
            lo, hi = ESTIMATE_SPREAD[key]
            spread = f"; measured runs took {lo:g}-{hi:g}x such estimates"
        if key.startswith("dfsph-coupled"):  # see _wall_estimate: its rate is 2 cores'
            scaled = "" if threads == 2 else f", not scaled to {threads} CPU thread(s)"
            return (f"; about {text} of wall time at the rates measured for {key} "
                    f"(validation/trade) on 2 cores{scaled}{spread}")
        return (f"; about {text} of wall time on {threads} CPU thread(s) at the rates measured "
                f"for {key} (validation/trade){spread}")

    # ----------------------------------------------------------------- building
    def build(self) -> None:
        if self._built:
            return
        from taichi_mex.core.grid import NeighbourGrid
        from taichi_mex.core.kernels import Kernel
        from taichi_mex.physics.viscosity_models import MeltViscosity
        from taichi_mex.sim.solver import SOLVERS
        from taichi_mex.core.state import ParticleState

        run = self.run_opts
        self.arch_used = backend.init(run.arch, run.precision, run.cpu_threads)
        from taichi_mex.core.timing import PhaseTimer

        self.timer = PhaseTimer(run.profile)
        kind, factor = run.resolved_kernel()
        dx = run.spacing_m
        self.kernel = Kernel(kind, factor * dx)
        self.state = ParticleState(self.estimate["capacity"], origin_m=self.plan.origin_m)
        self.thermal = None
        if "thermal" in self.plan.needs or run.thermal.enabled:
            from taichi_mex.physics.thermal import Thermal

            self.thermal = Thermal(self.state, self.kernel, dx, self.material, run.thermal,
                                   clock=lambda: self.time_s)
        self.solidification = None
        if self.thermal is not None and run.scheme != "static":
            from taichi_mex.physics.solidification import Solidification

            self.solidification = Solidification(self.state, self.thermal.T,
                                                 self.material.no_flow_temperature_c)
        self.viscosity = MeltViscosity(self.state, self.material,
                                       self.thermal.T if self.thermal else None,
                                       scale=self.viscosity_scale)
        skin = (run.edac.list_skin if run.scheme == "edac" else 0.0) * self.kernel.H
        self.grid = NeighbourGrid(self.state, self.plan.domain_lo_m, self.plan.domain_hi_m,
                                  self.kernel.H, self.estimate["max_neighbours"], skin_m=skin,
                                  # without heat a window's substrate is a wall: most of it
                                  # is out of the melt's reach and needs no list
                                  solid_lists=self.thermal is not None)
        self.state.on_append.append(lambda _sl, _ph: setattr(self.grid, "stale", True))
        self.viscosity.attach(self.grid, self.kernel)
        from taichi_mex.physics.surface import SurfaceDetector

        self.surface = SurfaceDetector(self.state, dx, self.grid, self.kernel)
        if self.thermal is not None:
            self.thermal.attach(self.grid, self.surface)
        from taichi_mex.sim.solver import StepHooks

        hooks = StepHooks(refresh=self.refresh, refresh_lists=self.refresh_lists,
                          heat_step=self.heat_step, move_boundaries=self.move_boundaries,
                          diverged=self.diverged, extra_dt_limits=self.extra_dt_limits,
                          boundary_speed=self.boundary_speed, steps=lambda: self.steps,
                          phase=self.timer.phase)
        if run.dfsph.stokes_wall_ghost == "quadratic" and self.plan.t_end_s > self.plan.t_start_s:
            # measured on one solve at a fixed geometry only: a film between a plate and a lid
            # sliding past each other blew up at 2 ms under it (validation/couette); refused
            # before the solver's fields and kernels are built
            raise UserInputError(f"--wall-ghost quadratic is for scenes measured by one coupled "
                                 f"solve at a fixed geometry (couette, squeeze-film); the "
                                 f"{self.plan.name} scene runs in time: leave --wall-ghost at adami.")
        self.solver = SOLVERS[run.scheme](self.state, self.grid, self.kernel, self.viscosity,
                                          self.material.density_kg_m3, run, hooks,
                                          self.plan.speed_scale_m_s, self.plan.max_dt_s,
                                          material=self.material,
                                          melt_capacity=self.estimate["melt_capacity"])
        if getattr(self.solver, "stokes", None) is not None:
            self.solver.stokes.attach_surface(self.surface)
        if self.plan.drive is not None:
            if getattr(self.solver, "stokes", None) is None:
                raise UserInputError(f"The {self.plan.name} scene drives its melt by a body force "
                                     "that only the coupled solve reads: run it with "
                                     "--creeping-solve coupled.")
            (ax, ay, az), z_m = self.plan.drive
            self.solver.stokes.drive = (float(ax), float(ay), float(az),
                                        float(z_m - self.state.origin_m[2]))
        # DFSPH calibrates the particle volume so a rest lattice has rho = rho0 exactly
        self.mass = getattr(self.solver, "particle_mass", self.material.density_kg_m3 * dx**3)
        self.inlet = None
        if self.plan.inlet is not None:
            from taichi_mex.sim.inlet import NozzleInlet

            spec = self.plan.inlet
            self.inlet = NozzleInlet(self.state, spec.selection, dx, self.kernel.H, self.mass,
                                     spec.z_offset_m, spec.tip_outer_diameter_m,
                                     spec.flank_angle_deg, spec.body_height_m)
        self._initial_fluid = self.plan.initial_count(FLUID)
        # the substrate below a print window's layer: melt printed before the run, not deposited
        self._initial_solid = self.plan.initial_count(SOLID)
        self.place(self.plan.blocks)
        if self.inlet is not None:
            self.inlet.build_tip(self.plan.t_start_s)
        if self.run_opts.probes_mm:
            from taichi_mex.post.probes import ProbeRecorder

            self.probes = ProbeRecorder(self.run_opts.probes_mm, self.kernel.W_np, self.kernel.H)
        self._built = True

    def place(self, blocks, replace: bool = False) -> None:
        """Create the particles of ``blocks`` (a plan's); replace=True: in place of every
        particle there is (a scene that rebuilds its geometry between solves)."""
        if replace:
            if sum(len(b.position_m) for b in blocks) > self.state.capacity:
                raise SimulationDiverged(f"The {self.plan.name} scene's new geometry needs more "
                                         f"than the {self.state.capacity:,} particles planned.")
            self.state.n = 0
            self.grid.stale = True
        for block in blocks:
            sl = self.state.append(block.position_m, block.phase, self.mass, block.velocity_m_s,
                                   density=self.material.density_kg_m3, bead=block.bead,
                                   time_s=self.plan.t_start_s)
            if block.wall_depth_m is not None:
                self.state.set_wall_surface(sl, block.wall_normal, block.wall_depth_m)
            if self.thermal is not None and block.temperature_c is not None:
                self.thermal.set_temperature(sl, block.temperature_c)

    # ----------------------------------------------------------------- stepping hooks
    def move_boundaries(self, t: float) -> int:
        """Move nozzle and inlet column, and any walls the scene moves itself, to time t;
        returns the particles released as melt."""
        move_walls = getattr(self.scene, "move_walls", None)
        if move_walls is not None:
            move_walls(self, t)
        if self.inlet is None or self._inlet_retired:
            return 0
        released = self.inlet.advance(t)
        if released:
            self.grid.stale = True  # new melt needs full neighbour lists
        return released

    def heat_step(self, dt: float) -> None:
        """Advance temperature by dt (solvers call this where neighbour lists and densities
        are current); solidify cooled melt."""
        if self.thermal is not None:
            self.thermal.step(dt)
            if self.solidification is not None and self.solidification.step():
                self.grid.stale = True

    def refresh_lists(self) -> None:
        """Re-sort and rebuild the neighbour lists now."""
        lost = self.grid.rebuild()
        if self.inlet is not None:
            self.inlet.mark_rebuilt()
        if lost:
            self.lost_particles += lost
            for face, count in self.grid.lost_last.items():
                self.lost_by_face[face] = self.lost_by_face.get(face, 0) + count
            self.lost_times_s = [self.lost_times_s[0] if self.lost_times_s else self.time_s,
                                 self.time_s]
        if self.grid.outside_last:
            self.outside_max = max(self.outside_max, sum(self.grid.outside_last.values()))
            for face, count in self.grid.outside_last.items():
                self.outside_by_face[face] = max(self.outside_by_face.get(face, 0), count)
            self.outside_times_s = [self.outside_times_s[0] if self.outside_times_s
                                    else self.time_s, self.time_s]
        if self.grid.overflowed():
            raise SimulationDiverged(
                f"At t = {self.time_s:.6g} s, {self.grid.overflowed()} particles had more than "
                f"{self.grid.max_neighbours} neighbours: the melt has clumped far beyond its "
                "rest spacing. " + self._likely_cause())
        self.viscosity.update(self.state.n)

    def _track_melt_over_face(self, t: float) -> None:
        """The melt over the nozzle's tip face (NozzleInlet.melt_over_face) after this step,
        and the step with the most: a count each step, the same whatever the output interval."""
        count = self.inlet.melt_over_face()
        melt = self.melt_particles()
        fraction = count / melt if melt > 0 else 0.0
        rec = self.over_face
        rec.update(melt_over_face_particles=count, melt_over_face_fraction=fraction,
                   melt_over_face_at_s=t)
        if fraction > rec["melt_over_face_fraction_max"]:
            rec.update(melt_over_face_fraction_max=fraction, melt_over_face_particles_max=count,
                       melt_over_face_max_at_s=t)

    def boundary_speed(self) -> float:
        """Fastest moving wall (the nozzle and the melt sliding down its bore), m/s."""
        speed = self.inlet.speed if self.inlet is not None and not self._inlet_retired else 0.0
        wall_speed = getattr(self.scene, "wall_speed", None)
        return max(speed, wall_speed()) if wall_speed is not None else speed

    def extra_dt_limits(self) -> dict:
        """Time-step limits of optional physics (heat), s."""
        return self.thermal.dt_limits() if self.thermal is not None else {}

    def refresh(self, t: float, fluid_moved_m: float = np.inf) -> None:
        """Move boundaries to time t; re-sort and rebuild the neighbour lists when they may be
        stale (always, without a skin); update the viscosity."""
        self.move_boundaries(t)
        moved = fluid_moved_m
        if self.inlet is not None and not self._inlet_retired:
            moved = max(moved, self.inlet.displacement_since_rebuild())
        if not self.grid.needs_rebuild(moved):
            self.viscosity.update(self.state.n)
            return
        self.refresh_lists()

    def _likely_cause(self) -> str:
        run = self.run_opts
        if run.dt_factor > 1:
            return (f"Likely cause: dt_factor = {run.dt_factor:g} takes the time step beyond the "
                    "limits it is measured at; use dt_factor <= 1.")
        if run.scheme == "edac":
            eta = self.material.viscosity_pa_s
            return (f"Likely cause: the explicit EDAC scheme (c_s = {run.edac.sound_speed_m_s} m/s, "
                    f"eta = {eta} Pa s) cannot hold the melt incompressible; raise the sound speed, "
                    "lower the CFL factor, or use --scheme dfsph.")
        return ("Likely cause: the time step is too large for the pressure solve to converge; lower "
                "the CFL factor or raise the iteration limits.")

    # ----------------------------------------------------------------- running
    def _idle_end(self, t: float, t_end: float) -> float | None:
        """End of the idle span that t lies in, if the run may skip it: the nozzle is outside
        the domain until then, the last step was creeping (inertia gone within a step), and
        the gravity slump rho g L T / eta over the span stays below creeping_limit (the bead
        would creep by less than that strain; Simulation._creeping_numbers)."""
        run = self.run_opts
        if not run.skip_idle or not self.plan.idle_windows or not getattr(self.solver, "creeping_now", False):
            return None
        for lo, hi in self.plan.idle_windows:
            if lo <= t < hi - 1e-12:
                end = min(hi, t_end)
                scales = self.plan.creeping
                eta = self.creeping.get("viscosity_as_run_pa_s")
                if scales is None or not eta:
                    return None
                slump = (self.material.density_kg_m3 * run.gravity_m_s2 * scales.length_m
                         * (end - t) / eta)
                return end if slump < run.creeping_limit else None
        return None

    def _idle_step(self, t: float, end: float) -> float:
        """Advance an idle span: heat alone at its own stable step, or straight to its end
        without heat; the nozzle then moves to where it re-enters."""
        if not self.skipped or self.skipped[-1]["to_s"] < t - 1e-12:
            self.skipped.append({"from_s": t, "to_s": t, "heat_steps": 0})
        span = self.skipped[-1]
        dt = end - t
        if self.thermal is not None:
            dt = min(min(self.extra_dt_limits().values()), dt)
            with self.timer.phase("heat (idle)"):
                self.heat_step(dt)
            span["heat_steps"] += 1
        t = end if end - (t + dt) < 1e-12 else t + dt
        span["to_s"] = t
        if t >= end:
            self.move_boundaries(t)
            self.grid.stale = True
            # the melt waited: a creeping melt's velocity follows its walls within a step, and
            # the nozzle's drag at the moment it left is long gone. Kept, it was inertia: a
            # fragment the nozzle had dragged flew on at its speed when the run came back
            # (benchy's window, t = 181.36 s)
            self.state.zero_velocity(FLUID)
            stokes = getattr(self.solver, "stokes", None)
            if stokes is not None:
                stokes.forget_history()
        return t

    def melt_particles(self) -> int:
        """Melt the solver moves: the scene's initial fluid plus what the inlet released, less
        what left the domain (the cost of a print should follow this, not the walls)."""
        released = self.inlet.released_count if self.inlet is not None else 0
        return self._initial_fluid + released - self.lost_particles

    def run(self, until_s: float | None = None, reporter=None) -> dict:
        """Advance to ``until_s`` (default: the scene's end) and return the summary dict.

        ``reporter``: an object with ``update(t_s, dt_s, particles)`` and ``close()`` that is
        told about every step (the command line's progress bar); the library prints nothing.
        Ctrl-C stops after the current step; every frame written so far stays valid and the
        summary says ``"interrupted": true``.
        """
        self.build()
        run = self.run_opts
        t_end = self.plan.t_end_s if until_s is None else min(until_s, self.plan.t_end_s)
        span = max(t_end - self.plan.t_start_s, 1e-12)
        every = run.output_every_s or span / (run.animation_frames if run.animation else 10.0)
        if not self.resumed:
            self.lost_particles = 0
            self.lost_by_face = {}
            self.lost_times_s = []
            self.outside_max = 0
            self.outside_by_face = {}
            self.outside_times_s = []
            self.over_face = _over_face_record()
            self._inlet_retired = False
            self.skipped = []
        writer = self._open_writer()
        t = self.time_s
        t0 = self.plan.t_start_s
        # a resumed run's frame at t is written: it continues on the same frame times
        next_out = _after(t0, every, t) if self.resumed else t
        snap_every = run.snapshot_every_s
        next_snap = _after(t0, snap_every, t) if snap_every else np.inf
        probe_every = run.probe_every_s or span / 200.0
        next_probe = t if run.probes_mm else np.inf
        interrupted = False
        error = None
        wall0 = time.perf_counter()
        particle_steps = melt_steps = 0
        dt_limits = {}
        speed_limit = run.max_speed_m_s or max(1.0, 20.0 * self.plan.speed_scale_m_s)
        monitor = getattr(self.scene, "monitor", None)
        self.solver.start(t)
        try:
            while True:
                # after a skipped idle span several output times may lie behind t: one
                # frame (sample) for all of them, then the next time ahead
                if writer is not None and t >= next_out - 1e-12:
                    self._write_frame(writer, t)
                    next_out = _after(t0, every, t)
                if writer is not None and t >= next_snap - 1e-12:
                    self.snapshots_or_warn(f"t{t:.5f}s")
                    next_snap = _after(t0, snap_every, t)
                if t >= next_probe - 1e-12:
                    self._sample_probes(t)
                    next_probe = _after(t0, probe_every, t)
                if t >= t_end - 1e-12:
                    break
                idle_end = self._idle_end(t, t_end)
                if idle_end is not None:
                    t = self._idle_step(t, idle_end)
                    self.time_s = t
                    if reporter is not None:
                        reporter.update(t, 0.0, self.state.n)
                    continue
                dt, dt_limits = self.solver.time_step()
                dt = _fit_step(dt * run.dt_factor, t_end - t)
                if not np.isfinite(dt) or dt <= 0:
                    raise SimulationDiverged(f"At t = {t:.6g} s the time step became {dt}. "
                                             + self._likely_cause())
                dt = self.solver.step(t, dt)
                t += dt
                self.time_s = t
                self.steps += 1
                particle_steps += self.state.n
                melt_steps += self.melt_particles()
                if self.inlet is not None and not self._inlet_retired:
                    self._track_melt_over_face(t)
                    if t > self.plan.inlet.selection.t_end_s:
                        self.inlet.retire()
                        self._inlet_retired = True
                if monitor is not None:
                    monitor(self, t)
                speed = self.solver.max_speed()
                if speed > speed_limit:
                    self.diverged(t, f"the fastest melt particle moves at {speed:.3g} m/s "
                                     f"(limit {speed_limit:.3g} m/s)")
                if reporter is not None:
                    reporter.update(t, dt, self.state.n)
        except KeyboardInterrupt:
            interrupted = True
        except SimulationDiverged as exc:
            error = exc
        finally:
            if reporter is not None:
                reporter.close()
        wall = time.perf_counter() - wall0
        # the state a run stopped in is its most telling frame: kept when interrupted, and
        # when it blew up with finite values (a particle over the speed limit, say)
        if writer is not None and (interrupted or (error is not None and all(
                np.isfinite(self.state.numpy(f)).all() for f in ("position", "velocity")))):
            self._write_frame(writer, t)
        summary = self.summary(wall, particle_steps, dt_limits)
        summary["skipped_spans"] = self.skipped
        summary["skipped_time_s"] = float(sum(s["to_s"] - s["from_s"] for s in self.skipped))
        summary["melt_particle_steps_per_s"] = float(melt_steps / wall) if wall > 0 else 0.0
        if run.profile:
            summary["phase_seconds"] = dict(sorted(self.timer.seconds.items(), key=lambda kv: -kv[1]))
        summary["interrupted"] = interrupted
        if error is not None:
            summary["error"] = str(error)
        if writer is not None:
            writer.close()
            self._finish_outputs(summary)
        if error is not None:
            raise error
        return summary

    def diverged(self, t: float, what: str) -> None:
        raise SimulationDiverged(f"The simulation blew up at t = {t:.6g} s: {what}. Frames "
                                 "written so far are kept, and the state it stopped in where "
                                 "it is finite. " + self._likely_cause())

    # ----------------------------------------------------------------- output
    def config_dict(self) -> dict:
        sec = self.plan.section_point_m
        direction = self.plan.section_direction
        return {"scene": self.plan.name, "run": to_dict(self.run_opts), "material": to_dict(self.material),
                "info": self.plan.info, "arch": getattr(self, "arch_used", None),
                "spacing_m": self.run_opts.spacing_m,
                "section_point_m": None if sec is None else [float(v) for v in sec],
                "section_direction": None if direction is None else [float(v) for v in direction]}

    def output_fields(self) -> list[str]:
        fields = ["velocity", "density", "pressure", "bead_id", "phase"]
        if self.thermal is not None:
            fields.append("temperature")
        return fields

    def _sample_probes(self, t: float) -> None:
        temperature = self.state.numpy("temperature") if self.thermal is not None else None
        self.probes.sample(t, self.state.numpy("position"), self.state.numpy("velocity"),
                           temperature)

    def frame_data(self) -> dict:
        phase = self.state.phase.to_numpy()[: self.state.n]
        keep = phase != PLATE
        data = {"position": self.state.numpy("position")[keep]}
        for name in self.output_fields():
            data[name] = self.state.numpy(name)[keep]
        return data

    def description(self):
        """The run description that re-creates this run (written as config.json); None for a
        scene built in Python that no registered scene describes."""
        from taichi_mex.spec import RunSpec, scene_entries

        entry = scene_entries().get(getattr(self.scene, "name", None))
        if entry is None or not isinstance(getattr(self.scene, "options", None), entry.options):
            return None
        return RunSpec(self.scene.name, self.scene.options, self.run_opts, self.material, self.preset,
                       self.material_source)

    def _open_writer(self):
        if self.out_dir is None:
            return None
        description = self.description()
        if description is not None:
            description.write(self.out_dir)
            self._description = description.to_dict()
        else:
            log.warning("scene '%s' is not a registered scene: no config.json (the run cannot be "
                        "re-created from a file)", getattr(self.scene, "name", "?"))
        from taichi_mex.post.output import FrameWriter

        writer = FrameWriter(self.out_dir, self.config_dict(), self.plan.name, self.output_fields(),
                             resume_at_s=self.time_s if self.resumed else None)
        if not self.resumed:
            writer.write_plate(self.state.numpy("position", PLATE))
        return writer

    def _write_frame(self, writer, t: float) -> None:
        with self.timer.phase("output and checkpoint"):
            writer.write_frame(t, self.steps, self.frame_data())
            if self._description is not None:
                from taichi_mex.sim import checkpoint

                checkpoint.save(self, self._description)

    @classmethod
    def resume(cls, out_dir) -> "Simulation":
        """The run in ``out_dir`` (its config.json and checkpoint.pkl), put back where its
        last checkpoint left it; ``run()`` then continues it to its end."""
        from taichi_mex.sim import checkpoint
        from taichi_mex.spec import RunSpec

        out_dir = Path(out_dir)
        if not (out_dir / "config.json").is_file():
            raise UserInputError(f"{out_dir} holds no config.json: not a taichi_mex run folder.")
        data = checkpoint.load(out_dir)
        spec = RunSpec.load(out_dir / "config.json")
        if data["description"] != spec.to_dict():
            raise UserInputError(f"{out_dir}/config.json differs from the run its checkpoint "
                                 "belongs to: resume refuses a changed configuration (start a new "
                                 "run with --config instead).")
        sim = cls.from_spec(spec, out_dir=out_dir)
        if data["run"]["time_s"] >= sim.plan.t_end_s - 1e-12:
            raise UserInputError(f"The run in {out_dir} already reached its end (t = "
                                 f"{data['run']['time_s']:.6g} s); nothing to resume.")
        sim.build()
        checkpoint.restore(sim, data)
        sim.resumed = True
        return sim

    def _finish_outputs(self, summary: dict) -> None:
        if hasattr(self.scene, "write_outputs") and "error" not in summary:
            self.scene.write_outputs(self, self.out_dir)
        summary.update(getattr(self, "bead_metrics", {}) or {})
        meso = getattr(self, "mesostructure", None)
        if meso and meso.get("sections"):
            from taichi_mex.post.analysis import headline_section

            first = headline_section(meso)
            if "width_min_mm" in first:
                summary["bead_width_range_mm"] = [first["width_min_mm"], first["width_max_mm"]]
                summary["bead_height_range_mm"] = [first["height_min_mm"], first["height_max_mm"]]
                summary["bead_sections"] = first["sections"]
            summary["bead_width_mm"] = first.get("mean_width_mm")
            summary["bead_height_mm"] = first.get("mean_height_mm")
            for key in ("top_min_mm", "top_median_mm", "top_max_mm"):
                summary["bead_" + key] = first.get(key)
            summary["bead_area_mm2"] = first.get("mean_area_mm2")
            summary["void_fraction"] = first.get("void_fraction")
        if self.probes is not None:
            self.probes.write(self.out_dir)
        (self.out_dir / "summary.json").write_text(json.dumps(summary, indent=2, default=float))
        if self.run_opts.snapshots:
            self.snapshots_or_warn("final")
        if self.run_opts.animation:
            try:
                self.animation()
            except Exception as exc:  # noqa: BLE001 - a view of the results, not the results
                log.warning("animation skipped: %s", exc)
        from taichi_mex.post.report import write_report

        write_report(self.out_dir)

    def snapshots_or_warn(self, tag: str) -> None:
        """Snapshots are a view of the results, not the results: a rendering failure is
        reported and the run goes on."""
        try:
            self.snapshots(tag)
        except Exception as exc:  # noqa: BLE001 - VTK raises assorted errors without a display
            log.warning("snapshots '%s' skipped: %s", tag, exc)

    def snapshots(self, tag: str, field: str | None = None) -> list:
        from taichi_mex.post.render import snapshot_set

        data = self.frame_data()
        field = field or self.run_opts.snapshot_field
        if field not in data:
            field = "density"
        return snapshot_set(data, self.out_dir / "snapshots", tag, field, self.run_opts.spacing_m,
                            self.plan.section_point_m, self.plan.section_direction,
                            self.picture_reference(), self.time_s)

    def picture_reference(self) -> dict:
        """What the pictures' colour ranges are set against."""
        ref = {"density_kg_m3": self.material.density_kg_m3}
        if self.thermal is not None:
            th = self.run_opts.thermal
            ref["temperature_range_c"] = (min(th.plate_temperature_c, th.ambient_c),
                                          self.material.extrusion_temperature_c)
        return ref

    def animation(self) -> Path:
        """animation.mp4 (or .gif) of the frames written so far."""
        from taichi_mex.post.output import read_frames
        from taichi_mex.post.render import write_animation

        field = self.run_opts.snapshot_field
        frames = read_frames(self.out_dir / "particles.h5")
        if frames and field not in frames[0]:
            field = "density"
        return write_animation(frames, self.out_dir / "animation.mp4", field,
                               self.run_opts.spacing_m, self.plan.section_direction,
                               self.picture_reference())

    # ----------------------------------------------------------------- results
    def density_errors(self) -> dict:
        """Two honest measures of incompressibility at the end of the run:

        * density_error_mean/max: |rho/rho0 - 1| over melt particles whose whole kernel
          support is melt or wall (a free-surface particle's summation density is short of
          rho0 by construction, up to ~50 %, whatever the solver does);
        * compression_error_mean/max: max(rho/rho0 - 1, 0) over all melt, the measure DFSPH
          controls and the literature reports.
        """
        from taichi_mex.physics.surface import interior_mask

        rho = self.state.numpy("density", FLUID).astype(np.float64)
        if len(rho) == 0:
            return {"density_error_mean": 0.0, "density_error_max": 0.0, "interior_particles": 0,
                    "compression_error_mean": 0.0, "compression_error_max": 0.0}
        rel = rho / self.material.density_kg_m3 - 1.0
        err = np.abs(rel)
        interior = interior_mask(self.surface)
        core = err[interior] if interior.any() else err
        compression = np.maximum(rel, 0.0)
        return {"density_error_mean": float(core.mean()), "density_error_max": float(core.max()),
                "interior_particles": int(interior.sum()),
                "paired_fraction": self.paired_fraction(),
                "density_error_max_all": float(err.max()),
                "compression_error_mean": float(compression.mean()),
                "compression_error_max": float(compression.max())}

    def paired_fraction(self, closer_than_dx: float = 0.5) -> float:
        """Fraction of fluid melt with a melt neighbour closer than ``closer_than_dx`` spacings:
        SPH's tensile pairing, which summation density cannot see (physics/pairing.py).
        A lattice gives 0; the single bead run without tension in the melt 0.5-0.9 %."""
        from taichi_mex.physics.pairing import PairingProbe

        if self._pairing is None:
            self._pairing = PairingProbe(self.state, self.grid)
        return self._pairing.paired_fraction(closer_than_dx * self.run_opts.spacing_m)

    def summary(self, wall_s: float, particle_steps: int, dt_limits: dict) -> dict:
        phase = self.state.phase.to_numpy()[: self.state.n]
        counts = {PHASE_NAMES[k]: int((phase == k).sum()) for k in PHASE_NAMES}
        # melt the run holds (solidified melt included), less the substrate it started on
        melt = int(((phase == FLUID) | (phase == SOLID)).sum()) - self._initial_solid
        vol_particle = self.run_opts.spacing_m**3
        out = {
            "scene": self.plan.name,
            "scheme": self.run_opts.scheme,
            "spacing_mm": self.run_opts.spacing_mm,
            "particles_active": int(self.state.n),
            "particles_by_phase": counts,
            # melt dropped: only positions that are not finite (a blow-up stops the run)
            "particles_lost": int(self.lost_particles),
            "particles_lost_by_face": dict(self.lost_by_face),
            "particles_lost_between_s": [float(t) for t in self.lost_times_s],
            # melt outside the domain's box, kept and searched in its edge cells: the most at
            # once, the most beyond each face (grid.FACES), first and last time
            "melt_outside_domain_max": int(self.outside_max),
            "melt_outside_domain_by_face": dict(self.outside_by_face),
            "melt_outside_domain_between_s": [float(t) for t in self.outside_times_s],
            "deposited_volume_mm3": melt * vol_particle * 1e9,
            "simulated_time_s": float(self.time_s - self.plan.t_start_s),
            "end_time_s": float(self.time_s),
            "wall_time_s": float(wall_s),
            "steps": int(self.steps),
            "particle_steps_per_s": float(particle_steps / wall_s) if wall_s > 0 else 0.0,
            # a quasi-static scene (one solve, no time) has no such figure: None, not 1e300
            "wall_time_per_simulated_s": (float(wall_s / (self.time_s - self.plan.t_start_s))
                                          if self.time_s > self.plan.t_start_s else None),
            "last_dt_limits_s": {k: float(v) for k, v in dt_limits.items()},
            "arch": getattr(self, "arch_used", None),
            "cpu_threads": backend.current().get("threads") if getattr(self, "arch_used", None) == "cpu" else None,
            "precision": self.run_opts.precision,
            "neighbour_rebuilds": int(self.grid.rebuilds),
        }
        out["estimate"] = {k: self.estimate[k] for k in ("particles", "steps_estimate",
                                                         "wall_time_estimate_s", "memory_bytes")}
        if self.plan.commanded_volume_m3 is not None:
            out["commanded_volume_mm3"] = float(self.plan.commanded_volume_m3(self.time_s)) * 1e9
        if self.inlet is not None:
            out["released_volume_mm3"] = self.inlet.released_volume_m3 * 1e9
            # melt over the tip face: at the last step the nozzle was present (it leaves with
            # the selection's last move), and the most at any step
            if self.over_face["melt_over_face_at_s"] is not None:
                out.update(self.over_face)
        out.update(self.density_errors())
        out.update({f"creeping_{k}" if not k.startswith("viscosity") else k: v
                    for k, v in self.creeping.items()})
        out.update(self.solver.diagnostics())
        if self.thermal is not None:
            out.update(self.thermal.summary())
        if self.solidification is not None:
            out["solidified_particles"] = int(self.solidification.count)
        if hasattr(self.scene, "analyse"):
            out.update(self.scene.analyse(self))
        return out


def _over_face_record() -> dict:
    """Melt over the nozzle's tip face, under summary.json's names: the latest step's count
    and fraction of the run's melt, and the step that had the most (times None: no step with
    a nozzle yet)."""
    return {"melt_over_face_particles": 0, "melt_over_face_fraction": 0.0,
            "melt_over_face_at_s": None, "melt_over_face_fraction_max": 0.0,
            "melt_over_face_particles_max": 0, "melt_over_face_max_at_s": None}


def _after(t0: float, every: float, t: float) -> float:
    """The first of the times t0 + k every that lies after t (t itself within rounding counts
    as reached)."""
    return t0 + every * (np.floor((t - t0) / every + 1e-9) + 1)


def _fit_step(dt: float, remaining: float) -> float:
    """Shorten dt so the remaining time splits into equal steps: no sliver of a last step
    (an implicit pressure solve would correct a whole step's density error in it)."""
    if remaining <= dt:
        return remaining
    steps = np.ceil(remaining / dt - 1e-9)
    return remaining / steps if steps <= 3 else dt
