"""Rows of particles split into one contiguous share of equal work per CPU thread.

Taichi's CPU backend (1.7) runs a parallel range-for as one contiguous chunk of the range per
thread, not as tasks taken in turn: a loop of 143,000 iterations whose work lay in its first
half took 47.6 ms on 2 threads and 47.4 ms on one (2 cores, 2026-12-05). A loop over every
particle that works on the melt only, or over rows whose neighbour counts differ between the
two halves, leaves a thread idle for the difference: in the dam break the first half of the
storage order holds 53,267 of the 80,703 fluid particles, and its EDAC step kept the 2 cores
busy 70 % of the time. Here the rows stay in storage order (neighbours of consecutive rows
share cache lines) and are cut where the summed work crosses each thread's fraction; the
loop runs over threads x the longest share, so that each thread's chunk is its share, and
the few iterations past a shorter share do nothing. On a GPU there is one share.
"""

from taichi_mex.backend import current, ti


@ti.data_oriented
class ThreadShares:
    """Fill ``rows[0..n)`` and ``weight[0..n)`` (the work of each row, any unit), call
    :meth:`split`, then loop ``for k in range(shares.span[None])`` with ``i = shares.row(k)``
    and skip ``i < 0``."""

    def __init__(self, capacity: int, threads: int | None = None):
        """threads: shares to cut (None: Taichi's CPU threads, one on a GPU)."""
        if threads is None:
            info = current()
            threads = int(info.get("threads") or 1) if info.get("arch") == "cpu" else 1
        self.threads = max(1, int(threads))
        self.rows = ti.field(ti.i32, shape=capacity)
        self.weight = ti.field(ti.i32, shape=capacity)
        self.bounds = ti.field(ti.i32, shape=self.threads + 1)  # share t: rows[bounds[t]..bounds[t+1])
        self.share = ti.field(ti.i32, shape=())  # the longest share
        self.span = ti.field(ti.i32, shape=())  # the loop's length: threads x share

    def split(self, n: int) -> None:
        self._split(int(n))

    @ti.kernel
    def _split(self, n: ti.i32):
        ti.loop_config(serialize=True)
        for _ in range(1):
            T = self.threads
            total = ti.cast(0, ti.i64)
            for k in range(n):
                total += self.weight[k]
            self.bounds[0] = 0
            t = 1
            done = ti.cast(0, ti.i64)
            for k in range(n):
                done += self.weight[k]
                while t < T and done * T >= total * t:
                    self.bounds[t] = k + 1
                    t += 1
            while t <= T:
                self.bounds[t] = n
                t += 1
            longest = 0
            for s in range(T):
                longest = ti.max(longest, self.bounds[s + 1] - self.bounds[s])
            self.share[None] = longest
            self.span[None] = T * longest

    @ti.func
    def row(self, k):
        """The row of loop index k in [0, span), or -1 past the end of a shorter share."""
        s = ti.max(self.share[None], 1)
        t = k // s
        j = self.bounds[t] + k % s
        i = -1
        if j < self.bounds[t + 1]:
            i = self.rows[j]
        return i
