"""Solidification: melt that cools below its no-flow temperature becomes a rigid solid.

A solid particle keeps its place and temperature (it still conducts), acts as a wall for the
remaining melt and drops out of the pressure and viscosity solves, so cooled layers carry
the next ones and cost almost nothing but their neighbour lists.
"""

from taichi_mex.backend import ti
from taichi_mex.core.state import FLUID, SOLID


@ti.data_oriented
class Solidification:
    def __init__(self, state, temperature, no_flow_temperature_c: float):
        self.state = state
        self.T = temperature
        self.T_nf = float(no_flow_temperature_c)
        self.count = 0

    def step(self) -> int:
        changed = int(self._freeze(self.state.n))
        self.count += changed
        return changed

    @ti.kernel
    def _freeze(self, n: ti.i32) -> ti.i32:
        changed = 0
        for i in range(n):
            if self.state.phase[i] == FLUID and self.T[i] < self.T_nf:
                self.state.phase[i] = SOLID
                self.state.v[i] = ti.Vector([0.0, 0.0, 0.0])
                changed += 1
        return changed
