"""Particle pairing: melt particles with a melt neighbour much closer than the spacing.

SPH under tension clumps particles into pairs (the tensile instability; Swegle et al. 1995,
Monaghan 2000). A pair at a fraction of a spacing still satisfies the summation density, so
density errors do not show it, but the pair leaves a particle-sized gap beside it, which a
cross-section reads as a void. This probe counts it, so that a summary can say so.
"""

from ..backend import ti
from ..state import FLUID, SOLID


@ti.data_oriented
class PairingProbe:
    def __init__(self, state, grid):
        self.state = state
        self.grid = grid
        self.nearest = ti.field(float, shape=state.capacity)

    @ti.func
    def _task(self, i, j, xij, acc: ti.template()):
        ph = self.state.phase[j]
        if ph == FLUID or ph == SOLID:
            acc = ti.min(acc, xij.norm())

    @ti.kernel
    def _measure(self, n: ti.i32):
        for i in range(n):
            d = 1e30
            if self.state.phase[i] == FLUID:
                self.grid.for_each_neighbour(i, self._task, d)
            self.nearest[i] = d

    def nearest_melt_distance(self):
        """Distance (m) from each live particle to its nearest melt neighbour within the
        kernel support (1e30 for none, and for particles that are not fluid)."""
        n = self.state.n
        self._measure(n)
        return self.nearest.to_numpy()[:n]
