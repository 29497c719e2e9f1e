"""One time step per scheme: the enabled methods in the order their papers give."""

import numpy as np

from .physics.edac import EDAC


class EDACSolver:
    """PySPH's PEC midpoint integration of the EDAC equations (one evaluation per step):

    1. predict x, v, p to t + dt/2 with the last rates      (EDACStep.stage1)
    2. move the nozzle, re-sort, evaluate rates at t + dt/2 (Eq. 10, momentum, walls)
    3. correct from t to t + dt with the midpoint rates     (EDACStep.stage2)
    """

    name = "edac"
    #: Verlet skin as a fraction of the support radius: EDAC steps move particles so little
    #: that lists built with it last dozens of steps
    list_skin = 0.15

    def __init__(self, sim):
        self.sim = sim
        opts = sim.run_opts
        self.edac = EDAC(sim.state, sim.grid, sim.kernel, sim.viscosity, opts.edac,
                         opts.gravity_m_s2, sim.material.density_kg_m3)
        self.t_eval = -np.inf
        self.stats = {}

    def start(self, t: float) -> None:
        self.sim.refresh(t)
        self._check(self.edac.evaluate(), t)
        self.t_eval = t

    def time_step(self) -> tuple[float, dict]:
        nu = self.sim.viscosity.max_value() / self.sim.material.density_kg_m3
        return self.edac.time_step(nu)

    def step(self, t: float, dt: float) -> None:
        e = self.edac
        moved = e.predict(self.sim.state.n, 0.5 * dt, self.t_eval)
        self.sim.refresh(t + 0.5 * dt, moved)
        self.t_eval = t + 0.5 * dt
        self._check(e.evaluate(dt, self.t_eval), t + dt)
        self.sim.move_boundaries(t + dt)

    def _check(self, nonfinite: int, t: float) -> None:
        if nonfinite:
            self.sim.diverged(t, f"{nonfinite} melt particles have non-finite velocities")

    def max_speed(self) -> float:
        return self.edac.extremes[0]

    def diagnostics(self) -> dict:
        return {}


SOLVERS = {"edac": EDACSolver}


def register(name: str, cls) -> None:
    SOLVERS[name] = cls
