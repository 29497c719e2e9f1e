"""Particle pairing: melt particles with a melt neighbour much closer than the spacing.

SPH under tension clumps particles into pairs (the tensile instability; Swegle et al. 1995,
Monaghan 2000). A pair at a fraction of a spacing still satisfies the summation density, so
density errors do not show it, but the pair leaves a particle-sized gap beside it, which a
cross-section reads as a void. This probe counts it, so that a summary can say so.
"""

from taichi_mex.backend import ti
from taichi_mex.core.state import FLUID, SOLID


@ti.data_oriented
class PairingProbe:
    def __init__(self, state, grid):
        self.state = state
        self.grid = grid

    @ti.func
    def _task(self, i, j, xij, acc: ti.template()):
        ph = self.state.phase[j]
        if ph == FLUID or ph == SOLID:
            acc = ti.min(acc, xij.norm())

    @ti.kernel
    def _count(self, n: ti.i32, r_pair: float) -> ti.types.vector(2, ti.i32):
        fluid = 0
        paired = 0
        for i in range(n):
            if self.state.phase[i] == FLUID:
                d = 1e30
                self.grid.for_each_neighbour(i, self._task, d)
                fluid += 1
                if d < r_pair:
                    paired += 1
        return ti.Vector([fluid, paired])

    def paired_fraction(self, r_pair_m: float) -> float:
        """Fraction of fluid particles with a melt neighbour closer than r_pair_m (0 without
        fluid)."""
        fluid, paired = (int(v) for v in self._count(self.state.n, r_pair_m))
        return paired / fluid if fluid else 0.0
