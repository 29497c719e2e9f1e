"""One time step per scheme: the enabled methods in the order their papers give.

A solver receives the particle state, the neighbour grid, the kernel, the melt viscosity, the
run options and the scene's scales, and a :class:`StepHooks`: the few services of the run loop
around it that a step calls (moving walls, rebuilding lists, heat, reporting a blow-up). It
never holds the Simulation. Every solver class takes the same arguments."""

import time
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from taichi_mex.backend import ti
from taichi_mex.errors import SimulationDiverged
from taichi_mex.physics.dfsph import DFSPH
from taichi_mex.physics.edac import EDAC
from taichi_mex.physics.stokes import CoupledStokes
from taichi_mex.physics.viscosity_weiler2018 import ImplicitViscosity
from taichi_mex.core.state import FLUID, FluidIndex


@dataclass
class StepHooks:
    """The run loop's services a solver's step calls (sim/simulation.py provides them).

    refresh(t, fluid_moved_m=inf): move the walls to time t, rebuild the neighbour lists when
        they may be stale (fluid moved fluid_moved_m since the last rebuild), update the
        viscosity;
    refresh_lists(): re-sort and rebuild the neighbour lists now, update the viscosity;
    heat_step(dt): advance temperature (and solidification) by dt, where lists and densities
        are current; a no-op without heat;
    move_boundaries(t): move the nozzle and the bore's melt column to time t;
    diverged(t, what): stop the run as blown up at time t (raises SimulationDiverged);
    extra_dt_limits(): time-step limits of optional physics, {name: s};
    boundary_speed(): the fastest moving wall, m/s;
    steps(): steps taken so far (for per-step diagnostics);
    phase(name): a context that times a phase of the step (core/timing.py; free when off).
    """

    refresh: Callable
    refresh_lists: Callable
    heat_step: Callable
    move_boundaries: Callable
    diverged: Callable
    extra_dt_limits: Callable
    boundary_speed: Callable
    steps: Callable
    phase: Callable


class EDACSolver:
    """PySPH's PEC midpoint integration of the EDAC equations (one evaluation per step):

    1. predict x, v, p to t + dt/2 with the last rates      (EDACStep.stage1)
    2. move the nozzle, re-sort, evaluate rates at t + dt/2 (Eq. 10, momentum, walls)
    3. correct from t to t + dt with the midpoint rates     (EDACStep.stage2)
    """

    name = "edac"

    def __init__(self, state, grid, kernel, viscosity, rho0: float, run, hooks: StepHooks,
                 speed_scale_m_s: float = 0.0, max_dt_s: float | None = None, material=None,
                 melt_capacity: int | None = None):
        self.state = state
        self.hooks = hooks
        self.viscosity = viscosity
        self.rho0 = float(rho0)
        self.edac = EDAC(state, grid, kernel, viscosity, run.edac, run.gravity_m_s2, rho0)
        self.t_eval = -np.inf
        self.stats = {}

    def start(self, t: float) -> None:
        self.hooks.refresh(t)
        self._check(self.edac.evaluate(), t)
        self.t_eval = t

    def time_step(self) -> tuple[float, dict]:
        nu = self.viscosity.max_value() / self.rho0
        _, limits = self.edac.time_step(nu)
        limits.update(self.hooks.extra_dt_limits())  # heat's diffusion limit, when heat is on
        return min(limits.values()), limits

    def step(self, t: float, dt: float) -> float:
        e = self.edac
        h = self.hooks
        with h.phase("predict"):
            moved = e.predict(self.state.n, 0.5 * dt, self.t_eval)
        with h.phase("neighbour search"):
            h.refresh(t + 0.5 * dt, moved)
        self.t_eval = t + 0.5 * dt
        with h.phase("rates and correct"):
            self._check(e.evaluate(dt, self.t_eval), t + dt)
        with h.phase("heat"):
            h.heat_step(dt)  # lists and densities are those of the midpoint state
        with h.phase("nozzle and inlet"):
            h.move_boundaries(t + dt)
        return dt

    def _check(self, nonfinite: int, t: float) -> None:
        if nonfinite:
            self.hooks.diverged(t, f"{nonfinite} melt particles have non-finite velocities")

    def max_speed(self) -> float:
        return self.edac.extremes[0]

    def diagnostics(self) -> dict:
        return {}


@ti.data_oriented
class DFSPHSolver:
    """Bender & Koschier (2017), Alg. 1, with Weiler et al. (2018) implicit viscosity:

    1. neighbour lists, densities rho_i and factors alpha_i at x_n
    2. divergence solve: make v_n divergence free                         (Alg. 2)
       (skipped by default in creeping steps, where the viscous solve sets the velocity:
       DFSPHOptions.divergence_solve)
    3. last step's pressure and gravity, v' = v_n - dt grad p_n / rho + dt g, then the implicit
       viscosity (I - dt/rho A_visc) v* = v' (Weiler 2018). With the pressure in the predictor
       a melt at rest sees no net force here: its weight stays on the pressure, not on
       friction at no-slip walls, and a creeping bead does not fall at g dt per step
    4. constant-density solve on v* for the pressure increment: v_{n+1}     (Alg. 3)
    5. x_{n+1} = x_n + dt v_{n+1}; the nozzle moves to t + dt

    This split solve is for inertial flows (creeping_solve = 'split'; a creeping melt is
    refused up front, Simulation._check_split_solve). With creeping_solve = 'coupled' (the
    default) steps 2-4 are one solve of viscous stress and pressure (physics/stokes.py).
    """

    name = "dfsph"
    #: the implicit viscosity caches one coefficient per neighbour-list slot
    cached_per_neighbour = 1

    def __init__(self, state, grid, kernel, viscosity, rho0: float, run, hooks: StepHooks,
                 speed_scale_m_s: float = 0.0, max_dt_s: float | None = None, material=None,
                 melt_capacity: int | None = None):
        """speed_scale_m_s: the scene's speed scale (its fastest nozzle move; unused here);
        max_dt_s: the scene's largest step (None: the option's); melt_capacity: the most melt
        particles the run can hold (None: all of them), which sizes the coupled solve's
        Krylov vectors."""
        self.state = state
        self.hooks = hooks
        self.opts = run.dfsph
        # a scene of slow creeping flow may allow longer steps than a print
        self.max_dt = float(max_dt_s or run.dfsph.max_dt_s)
        self.fluid = FluidIndex(state)
        # the split solve's rows are the fluid index the viscosity and coupled solves use
        self.dfsph = DFSPH(state, grid, kernel, run.dfsph, rho0, run.spacing_m, viscosity,
                           self.fluid)
        self.particle_mass = self.dfsph.mass
        self.g = ti.Vector([0.0, 0.0, -float(run.gravity_m_s2)])
        self.visc = ImplicitViscosity(state, grid, kernel, viscosity, self.particle_mass, rho0,
                                      run.spacing_m, run.dfsph.viscosity_tolerance,
                                      run.dfsph.viscosity_max_iterations, self.fluid,
                                      run.dfsph.no_slip, run.dfsph.cg_chunk)
        self.stokes = None
        if run.dfsph.creeping_solve == "coupled":
            bulk = material.bulk_modulus_pa if material is not None else None
            self.stokes = CoupledStokes(state, grid, kernel, viscosity, self.visc, rho0,
                                        self.dfsph.V0, run.spacing_m, self.fluid, run.dfsph,
                                        bulk_modulus_pa=bulk, rows_capacity=melt_capacity)
        self.gravity = (0.0, 0.0, -float(run.gravity_m_s2))
        self.max_travel = float(run.dfsph.max_travel_spacings)
        # the split solve (inertial scenes) keeps the absolute rule its travel check assumes
        self.relative = run.dfsph.time_step_speed == "relative" and self.stokes is not None
        self.grid = grid
        self.dt_factor = float(run.dt_factor)
        self._moves = 0  # steps advanced; the lists are fresh while _sorted_at equals it
        self._sorted_at = -1
        self.retries = int(run.dfsph.step_retries)
        self.vmax = 0.0
        self.dx = run.spacing_m
        self.halvings = 0
        # solves stopped by their iteration cap (each makes its step be redone)
        self.unconverged = {"divergence": 0, "viscosity": 0, "pressure": 0, "coupled": 0}
        cap = state.capacity
        self.saved_v = ti.Vector.field(3, float, shape=cap)
        self.saved_k = ti.Vector.field(2, float, shape=cap)
        self.saved_vdiff = ti.Vector.field(3, float, shape=cap)
        self.totals = {"density_iterations": 0, "divergence_iterations": 0, "viscosity_iterations": 0,
                       "stokes_iterations": 0, "stokes_inner_iterations": 0,
                       "stokes_free_steps": 0, "melt_speed_1_2x": 0, "melt_speed_2_4x": 0,
                       "melt_speed_over_4x": 0}
        self.worst = {"density_error": 0.0, "viscosity_residual": 0.0,
                      "stokes_momentum_residual": 0.0, "stokes_density_error": 0.0,
                      "stokes_free_rows": 0, "melt_speed": 0.0}
        # the densest melt at the start of every step: the state a step leaves, at any time,
        # not only at the end (a slice leaving the bore was compressed for one step)
        self.peak_compression = {"max": 0.0, "sum": 0.0, "steps": 0}
        self.last = {}

    def start(self, t: float) -> None:
        pass

    def time_step(self) -> tuple[float, dict]:
        """The CFL bound dt <= cfl 0.4 dx / u on the speed u of the motion that deforms the
        melt (time_step_speed = 'relative', under the coupled solve):

        - within the kernel's support H, u is the largest |v_i - v_j| over the melt's pairs
          (melt or wall j): no pair closes, opens or shears by more than cfl 0.4 dx in a step,
          Monaghan's (1992) pair speed without the sound speed, which a creeping solve has not;
        - from H to H + L (L one grid cell, H / 2), a pair closing at speed a enters the support
          by at most cfl 0.4 dx: dt <= (r - H + cfl 0.4 dx) / a;
        - beyond H + L no pair may reach H within the step: dt f <= L + f cfl 0.4 dx on the
          diameter of all velocities (f the run's dt_factor, which multiplies the step after).

        Melt riding rigidly with the nozzle across a travel move then takes steps about
        (L + cfl 0.4 dx) / (cfl 0.4 dx) = 6x longer (cfl 0.5) than the nozzle's speed would
        give; melt sheared under the face or pushed against the bead below keeps the step
        the nozzle's speed gives, and gravity-driven spreading the step its front's speed
        against the plate gives. 'absolute' takes u as the fastest melt or wall, as before.

        Before the first step, when no melt moves yet, Monaghan's (1992) force criterion
        dt <= 0.25 sqrt(h / g) on the force that starts it: melt released from rest then
        starts with the same step whatever the run's length or output interval. (Applied at
        every step to the step's own acceleration |dv| / dt it would hold dt near
        0.06 h / |dv|, below the CFL step wherever melt takes the nozzle's speed within one
        step, as a creeping melt does by design.)"""
        o = self.opts
        cfl_length = o.cfl * 0.4 * self.dx
        if self.relative:
            with self.hooks.phase("neighbour search"):
                self.hooks.refresh_lists()
            self._sorted_at = self._moves
            H = self.dfsph.K.H
            margin = self.grid.cell
            with self.hooks.phase("time step"):
                rates = self._closing_rates(self.state.n, H, margin, cfl_length)
            envelope = float(rates[1]) / (margin / self.dt_factor + cfl_length)
            limits = {"cfl": 1.0 / max(float(rates[0]), envelope, 1e-30), "max": self.max_dt}
        else:
            speed = max(self.vmax, self.hooks.boundary_speed(), 1e-6)
            limits = {"cfl": cfl_length / speed, "max": self.max_dt}
        g = abs(self.gravity[2])
        if self.hooks.steps() == 0 and g > 0.0:
            limits["force"] = 0.25 * (0.5 * self.dfsph.K.H / g) ** 0.5
        limits.update(self.hooks.extra_dt_limits())
        return min(limits.values()), limits

    @ti.kernel
    def _closing_rates(self, n: ti.i32, H: float, margin: float,
                       cfl_length: float) -> ti.types.vector(2, float):
        """(the melt's largest pair speed over its allowance in 1/s: |v_ij| / cfl_length
        within H, closing speed / (r - H + cfl_length) from H to H + margin; the diameter of
        the velocities of everything alive, m/s). Cells are scanned one further than the
        lists reach, on positions sorted this step."""
        lo0 = 1e30
        lo1 = 1e30
        lo2 = 1e30
        hi0 = -1e30
        hi1 = -1e30
        hi2 = -1e30
        for i in range(n):
            v = self.state.v[i]
            ti.atomic_min(lo0, v[0])
            ti.atomic_min(lo1, v[1])
            ti.atomic_min(lo2, v[2])
            ti.atomic_max(hi0, v[0])
            ti.atomic_max(hi1, v[1])
            ti.atomic_max(hi2, v[2])
        rate = 0.0
        R = H + margin
        for i in range(n):
            if self.state.phase[i] == FLUID:
                xi = self.state.x[i]
                vi = self.state.v[i]
                c = self.grid.cell_coords(xi)
                wide = self.grid.reach + 1
                for ox in range(-wide, wide + 1):
                    for oy in range(-wide, wide + 1):
                        js = self.grid.column(c, ox, oy, wide)
                        for j in range(js[0], js[1]):
                            xij = xi - self.state.x[j]
                            r2 = xij.norm_sqr()
                            if j != i and r2 < R * R:
                                vij = vi - self.state.v[j]
                                if r2 < H * H:
                                    ti.atomic_max(rate, vij.norm() / cfl_length)
                                else:
                                    r = ti.sqrt(r2)
                                    closing = -xij.dot(vij) / r
                                    ti.atomic_max(rate, closing / (r - H + cfl_length))
        diameter = ti.sqrt((hi0 - lo0) ** 2 + (hi1 - lo1) ** 2 + (hi2 - lo2) ** 2)
        if n == 0:
            diameter = 0.0
        return ti.Vector([rate, diameter])

    def _record_speed(self) -> None:
        """The step's fastest melt against the fastest wall (the nozzle in a print), binned:
        creeping melt moves no faster than what drives it, so steps well above it count melt
        that the solve flung (and that shortens the CFL step)."""
        self.worst["melt_speed"] = max(self.worst["melt_speed"], self.vmax)
        wall = self.hooks.boundary_speed()
        if wall > 0.0:
            ratio = self.vmax / wall
            for key, low, high in (("melt_speed_1_2x", 1, 2), ("melt_speed_2_4x", 2, 4),
                                   ("melt_speed_over_4x", 4, float("inf"))):
                self.totals[key] += low < ratio <= high

    @ti.kernel
    def _gravity(self, n: ti.i32, dt: float):
        for i in range(n):
            if self.state.phase[i] == FLUID:
                self.state.v[i] += dt * self.g

    # DFSPHOptions.max_travel_spacings: a step whose pressure solve leaves melt moving more
    # than this many spacings is redone with half the time step (the CFL bound uses the
    # velocities before the solve).

    @ti.kernel
    def _save(self, n: ti.i32):
        for i in range(n):
            self.saved_v[i] = self.state.v[i]
            self.saved_k[i] = ti.Vector([self.dfsph.kappa[i], self.dfsph.kappa_v[i]])
            self.saved_vdiff[i] = self.visc.vdiff[i]

    @ti.kernel
    def _restore(self, n: ti.i32):
        for i in range(n):
            self.state.v[i] = self.saved_v[i]
            self.dfsph.kappa[i] = self.saved_k[i][0]
            self.dfsph.kappa_v[i] = self.saved_k[i][1]
            self.visc.vdiff[i] = self.saved_vdiff[i]

    def step(self, t: float, dt: float) -> float:
        h = self.hooks
        if self._sorted_at != self._moves:  # time_step sorted them for this step
            with h.phase("neighbour search"):
                h.refresh_lists()
        self._moves += 1
        n = self.state.n
        d = self.dfsph
        with h.phase("densities and factors"):
            d.prepare(n)
        self._record_peak(float(d.rho_peak[None]) / d.rho0 - 1.0)
        with h.phase("heat"):
            h.heat_step(dt)  # at x_n, with this step's lists and densities
        self.fluid.update()  # after solidification too (the split solve's rows too)
        self._save(n)
        if self.stokes is not None:
            return self._coupled_step(t, dt, n)
        for attempt in range(self.retries + 1):
            if attempt:
                self._restore(n)
                dt *= 0.5
                self.halvings += 1
            converged = {}
            if self._divergence_solve_wanted(dt):
                with h.phase("divergence solve"):
                    iv, _ = d.divergence_solve(dt)
                converged["divergence"] = d.cg.converged()
                self.totals["divergence_iterations"] += iv
            d.pressure_predictor(n, d.rows.n, dt)
            self._gravity(n, dt)
            with h.phase("viscosity solve"):
                ik, res = self.visc.solve(dt)
            converged["viscosity"] = self.visc.cg.converged()
            with h.phase("density solve"):
                ip, err = d.density_solve(dt)
            converged["pressure"] = d.cg.converged()
            self.totals["viscosity_iterations"] += ik
            self.totals["density_iterations"] += ip
            vmax = float(d.max_fluid_speed(n))
            failed = [name for name, ok in converged.items() if not ok]
            for name in failed:
                self.unconverged[name] += 1
            if not failed and vmax * dt <= self.max_travel * self.dx:
                break
            if attempt == self.retries:
                if failed:
                    _stop(t, f"the {' and '.join(failed)} solve{'s' if len(failed) > 1 else ''} "
                             f"did not converge at dt = {dt:.3g} s after {self.retries} halvings "
                             "of the step. Raise run.dfsph.max_iterations or "
                             "run.dfsph.viscosity_max_iterations, or try --creeping-solve "
                             "coupled")
                break
        self.worst["viscosity_residual"] = max(self.worst["viscosity_residual"], res)
        self.worst["density_error"] = max(self.worst["density_error"], err)
        with h.phase("advance"):
            out = d.finish(n, dt, d.shifting * self.dx * self.dx)
        self.vmax = float(out[0])
        self._record_speed()
        if out[1] > 0:
            h.diverged(t + dt, f"{int(out[1])} melt particles have non-finite velocities after "
                                 "the pressure solve")
        # the step was creeping: viscous diffusion crossed the kernel, inertia is gone within
        # it (a run may then skip a span in which nothing drives the melt)
        self.creeping_now = bool(d.creeping(dt))
        self.last = {"density_iterations": ip, "viscosity_iterations": ik, "density_error": err,
                     "viscosity_residual": res, "dt": dt}
        with h.phase("nozzle and inlet"):
            h.move_boundaries(t + dt)
        return dt

    def _coupled_step(self, t: float, dt: float, n: int) -> float:
        """Viscous stress and pressure solved together (physics/stokes.py); a step whose solve
        does not converge is redone with half the step, and after step_retries halvings the
        run stops: no unconverged step is kept."""
        h = self.hooks
        d = self.dfsph
        for attempt in range(self.retries + 1):
            if attempt:
                self._restore(n)
                dt *= 0.5
                self.halvings += 1
            with h.phase("coupled solve"):
                res = self.stokes.solve(dt, d.kappa, self.gravity)
            self.totals["stokes_iterations"] += res.iterations
            self.totals["stokes_inner_iterations"] += res.inner_iterations
            if res.converged:
                break
            self.unconverged["coupled"] += 1
        else:
            _stop(t, f"the coupled viscous-pressure solve did not converge in "
                     f"{self.opts.stokes_max_iterations} iterations at dt = {dt:.3g} s after "
                     f"{self.retries} halvings of the step (momentum residual "
                     f"{res.momentum_residual:.2e}, largest density error "
                     f"{res.density_error_max:.2e}). Raise run.dfsph.stokes_max_iterations or "
                     "loosen run.dfsph.stokes_momentum_tolerance")
        w = self.worst
        w["stokes_momentum_residual"] = max(w["stokes_momentum_residual"], res.momentum_residual)
        w["stokes_density_error"] = max(w["stokes_density_error"], res.density_error_max)
        w["stokes_free_rows"] = max(w["stokes_free_rows"], res.free_rows)
        self.totals["stokes_free_steps"] += res.free_rows > 0
        with h.phase("advance"):
            out = self._advance(n, dt)
        self.vmax = float(out[0])
        self._record_speed()
        if out[1] > 0:
            h.diverged(t + dt, f"{int(out[1])} melt particles have non-finite velocities after "
                               "the coupled solve")
        self.creeping_now = bool(d.creeping(dt))
        self.last = {"stokes_iterations": res.iterations, "dt": dt,
                     "stokes_momentum_residual": res.momentum_residual,
                     "stokes_density_error": res.density_error_max}
        with h.phase("nozzle and inlet"):
            h.move_boundaries(t + dt)
        return dt

    @ti.kernel
    def _advance(self, n: ti.i32, dt: float) -> ti.types.vector(2, float):
        """x += dt v for the melt, pressure for output; (fastest melt, non-finite melt)."""
        vmax = 0.0
        bad = 0.0
        for i in range(n):
            if self.state.phase[i] == FLUID:
                s = self.state.v[i].norm()
                if ti.math.isnan(s) or ti.math.isinf(s):
                    bad += 1.0
                else:
                    ti.atomic_max(vmax, s)
                    rho = self.state.rho[i]
                    self.state.p[i] = self.dfsph.kappa[i] * rho * rho / self.dfsph.rho0
                    self.state.x[i] += dt * self.state.v[i]
        return ti.Vector([vmax, bad])

    def quasi_static(self):
        """One coupled solve at the present positions, nothing moved (a measurement: the
        squeeze film's force), with a step 1e6 times a spacing's viscous diffusion time, so
        that inertia is 1e-6 of the viscous forces; returns the solve's StokesResult, timed
        (wall_s: lists, densities and solve, with their first compilation)."""
        t0 = time.perf_counter()
        nu = self.visc.visc.min_value() / self.dfsph.rho0
        dt = 1e6 * self.dx * self.dx / nu
        self.hooks.refresh_lists()
        n = self.state.n
        self.dfsph.prepare(n)
        self.fluid.update()
        res = self.stokes.solve(dt, self.dfsph.kappa, self.gravity, compressible=False,
                                extrapolate=False)
        return replace(res, wall_s=time.perf_counter() - t0)

    def _record_peak(self, compression: float) -> None:
        if compression > -1.0:  # some melt present
            pk = self.peak_compression
            c = max(compression, 0.0)
            pk["max"] = max(pk["max"], c)
            pk["sum"] += c
            pk["steps"] += 1

    def _divergence_solve_wanted(self, dt: float) -> bool:
        wanted = self.opts.divergence_solve
        if wanted == "auto":
            return not self.dfsph.creeping(dt)
        return bool(wanted)

    def max_speed(self) -> float:
        return self.vmax

    def diagnostics(self) -> dict:
        steps = max(self.hooks.steps(), 1)
        return {
            "pressure_iterations_per_step": self.totals["density_iterations"] / steps,
            "divergence_iterations_per_step": self.totals["divergence_iterations"] / steps,
            "viscosity_iterations_per_step": self.totals["viscosity_iterations"] / steps,
            "pressure_error_worst": self.worst["density_error"],
            "viscosity_residual_worst": self.worst["viscosity_residual"],
            "time_step_halvings": self.halvings,
            "unconverged_solves_redone": dict(self.unconverged),
            "stokes_iterations_per_step": self.totals["stokes_iterations"] / steps,
            # the inner viscous iterations of the block-triangular preconditioner
            "stokes_inner_iterations_per_step": self.totals["stokes_inner_iterations"] / steps,
            # the coupled solve's solves by the operator their inner viscous solve inverted
            "stokes_inner_operator_solves": (
                {"weiler2018": self.stokes.inner_solves[False],
                 "system": self.stokes.inner_solves[True]} if self.stokes is not None else {}),
            # the share of Morris's term in the viscous pair terms as run (0 with the traction)
            "stokes_viscous_isotropic_share": (self.stokes.w_iso if self.stokes is not None
                                               else None),
            "stokes_momentum_residual_worst": self.worst["stokes_momentum_residual"],
            "stokes_density_error_worst": self.worst["stokes_density_error"],
            # melt torn off into fragments that touch nothing: steps with any, most at once
            "stokes_free_fragment_steps": self.totals["stokes_free_steps"],
            "stokes_free_fragment_particles_max": self.worst["stokes_free_rows"],
            # the fastest melt of the run, and the steps whose fastest melt outran the fastest
            # wall (the nozzle) by 1-2x, 2-4x, more
            "melt_speed_max_m_s": self.worst["melt_speed"],
            "melt_faster_than_walls_steps": {"1-2x": self.totals["melt_speed_1_2x"],
                                             "2-4x": self.totals["melt_speed_2_4x"],
                                             ">4x": self.totals["melt_speed_over_4x"]},
            # largest compression of any melt particle over all steps, and its mean over steps
            "compression_error_max_run": self.peak_compression["max"],
            "compression_error_step_max_mean": (self.peak_compression["sum"]
                                                / max(self.peak_compression["steps"], 1)),
        }


def _stop(t: float, what: str) -> None:
    raise SimulationDiverged(f"The simulation stopped at t = {t:.6g} s: {what}. No unconverged "
                             "step is kept; the frames written so far are.")


class StaticSolver:
    """No flow: particles stay where they are and only the enabled physics (heat) advances.
    For scenes such as the aluminium beam, whose solid does not move."""

    name = "static"

    def __init__(self, state, grid, kernel, viscosity, rho0: float, run, hooks: StepHooks,
                 speed_scale_m_s: float = 0.0, max_dt_s: float | None = None, material=None,
                 melt_capacity: int | None = None):
        self.hooks = hooks
        self.max_dt = float(max_dt_s or 1.0)

    def start(self, t: float) -> None:
        self.hooks.refresh_lists()

    def time_step(self) -> tuple[float, dict]:
        limits = dict(self.hooks.extra_dt_limits())
        limits.setdefault("max", self.max_dt)
        return min(limits.values()), limits

    def step(self, t: float, dt: float) -> float:
        with self.hooks.phase("heat"):
            self.hooks.heat_step(dt)
        return dt

    def max_speed(self) -> float:
        return 0.0

    def diagnostics(self) -> dict:
        return {}


SOLVERS = {"edac": EDACSolver, "dfsph": DFSPHSolver, "static": StaticSolver}


def register(name: str, cls) -> None:
    SOLVERS[name] = cls
