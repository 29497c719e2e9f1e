"""Deterministic parallel sums: fixed blocks summed in parallel, then the blocks in order.

Float atomics would make every solver's convergence test (and so its iteration count and
result) depend on thread timing; block sums give the same bits on every CPU run. The sums accumulate in f64 whatever the
state's precision (the conjugate-gradient solvers' dot products are these sums), so that a
solver's scalars do not carry f32 rounding of the block order into its iterations.
"""

import math

from taichi_mex.backend import ti

#: elements per block: a sum's grouping, and so its rounding, is fixed by it
BLOCK = 256


@ti.data_oriented
class BlockSum:
    def __init__(self, capacity: int, block: int = BLOCK):
        self.block = int(block)
        self.n_blocks = max(1, math.ceil(capacity / self.block))
        self.partial = ti.field(ti.f64, shape=self.n_blocks)
        self.total = ti.field(ti.f64, shape=())  # f64: read with ti.cast where f32 is wanted

    @ti.func
    def sum(self, values: ti.template(), n):
        """Sum values[0..n) into self.total[None] (call at a kernel's top level)."""
        nb = (n + self.block - 1) // self.block
        for b in range(nb):
            s = ti.cast(0.0, ti.f64)
            for k in range(b * self.block, ti.min((b + 1) * self.block, n)):
                s += ti.cast(values[k], ti.f64)
            self.partial[b] = s
        ti.loop_config(serialize=True)
        for _ in range(1):
            s = ti.cast(0.0, ti.f64)
            for b in range(nb):
                s += self.partial[b]
            self.total[None] = s

    @ti.func
    def max(self, values: ti.template(), n):
        """Largest of values[0..n) (non-negative values) into self.total[None]. Blocks first:
        an atomic max per particle on one shared variable has two cores fight over a cache
        line on every element (measured: ~15 % of an EDAC step at 143k particles)."""
        nb = (n + self.block - 1) // self.block
        for b in range(nb):
            s = ti.cast(0.0, ti.f64)
            for k in range(b * self.block, ti.min((b + 1) * self.block, n)):
                s = ti.max(s, ti.cast(values[k], ti.f64))
            self.partial[b] = s
        ti.loop_config(serialize=True)
        for _ in range(1):
            s = ti.cast(0.0, ti.f64)
            for b in range(nb):
                s = ti.max(s, self.partial[b])
            self.total[None] = s
