"""Uniform neighbour grid: counting sort by cell with a prefix sum, data reordered for locality.

Cells are cubes of edge H / k (k = ``cells_per_support``, default 2), indexed
``(ix * ny + iy) * nz + iz``, so for a particle the cells iz-k..iz+k of one (ix, iy) column are
contiguous in the sorted arrays: a query visits (2k+1)^2 contiguous ranges. Halving the cell
scans ~40 % fewer candidates than cells of edge H.

After the sort each particle's neighbours (j != i, |x_ij| < H + skin) are written to a
fixed-width list, so that physics loops and the iterative solvers read ~30-80 entries per particle
instead of scanning ~200 candidates in 27 cells each pass. A list that would overflow its
width means particles have clumped far beyond the rest spacing; the step reports it.

With a skin (Verlet lists), the lists stay valid until some particle has moved skin/2
since the rebuild: the explicit EDAC scheme, whose steps move particles by well under 1 %
of a spacing, then re-sorts only every few dozen steps. Queries still test |x_ij| < H.
Such lists are also packed end to end (counted in a first scan of the cells, then filled)
instead of sitting in rows of the fixed width: a row is sized for clumped melt, ~3x the
usual list, and reading lists spread over rows that are mostly empty cost as much as the
physics (143k-particle dam break: 10 ms against 1.6 ms packed, per pass over the lists).
Without a skin the lists are rebuilt every step, where the second scan would cost more
than the packing saves.

On the CPU the scatter runs serially, which keeps the order inside a cell (and therefore
every floating-point sum) identical from run to run; GPUs scatter with atomics.
"""


import math

import numpy as np

from taichi_mex.backend import current, ti
from taichi_mex.core.state import FLUID, SOLID, shape_bucket

#: the faces of the domain's box that melt outside it is beyond
FACES = ("x_min", "x_max", "y_min", "y_max", "bottom", "top")
N_FACES = len(FACES)  # a plain int for the kernels


@ti.data_oriented
class NeighbourGrid:
    def __init__(self, state, lo_m, hi_m, support_radius_m: float, max_neighbours: int = 96,
                 cells_per_support: int = 2, skin_m: float = 0.0, solid_lists: bool = True):
        """solid_lists: solidified melt gets a list of its own (heat conducts through it);
        False: only where melt sees it, as a wall (a print window's substrate without heat)."""
        self.state = state
        self.solid_lists = bool(solid_lists)
        self.H = float(support_radius_m)
        self.skin = float(skin_m)
        self.R = self.H + self.skin  # list radius
        self.reach = int(cells_per_support)
        self.cell = self.R / self.reach
        self.stale = True  # particles were added or changed role: lists must be rebuilt
        self.rebuilds = 0
        lo = np.asarray(lo_m, dtype=np.float64) - state.origin_m
        hi = np.asarray(hi_m, dtype=np.float64) - state.origin_m
        self.dims = tuple(max(1, int(math.ceil((hi[k] - lo[k]) / self.cell))) for k in range(3))
        self.n_cells = self.dims[0] * self.dims[1] * self.dims[2]
        # the grid's corner and shape are read from fields, and the cells' arrays are a
        # shape_bucket long (the rest stay empty): another domain of about the same size then
        # reuses the compiled kernels (core/state.py, SHAPE_BITS)
        self.lo_f = ti.Vector.field(3, float, shape=())
        self.lo_f[None] = tuple(float(v) for v in lo)
        self.dims_f = ti.Vector.field(3, ti.i32, shape=())
        self.dims_f[None] = self.dims
        self.n_alloc = shape_bucket(self.n_cells)
        cap = state.capacity
        self.cell_of = ti.field(ti.i32, shape=cap)
        self.perm = ti.field(ti.i32, shape=cap)
        # buckets: the cells, then DROPPED (positions that are not finite)
        self.dropped_bucket = self.n_alloc
        self.count = ti.field(ti.i32, shape=self.n_alloc + 1)
        self.start = ti.field(ti.i32, shape=self.n_alloc + 2)
        self.block = 1024
        # block sums of the scans over the cells and (packed lists) over the particles
        n_blocks = max(1, int(math.ceil(max(self.n_alloc + 1, cap) / self.block)))
        self.block_sum = ti.field(ti.i32, shape=n_blocks + 1)
        self.max_neighbours = int(max_neighbours)
        self.packed = self.skin > 0.0
        # particle i's list is nbr[row(i) .. row(i) + n_nbr[i]): row(i) = i * max_neighbours,
        # or list_start[i] when packed; at most max_neighbours entries either way
        self.nbr = ti.field(ti.i32, shape=cap * self.max_neighbours)
        self.n_nbr = ti.field(ti.i32, shape=cap)
        self.list_start = ti.field(ti.i32, shape=cap + 1)
        #: neighbours within H, at the front of each list after a partitioning pass
        self.n_support = ti.field(ti.i32, shape=cap)
        self.wall_needed = ti.field(ti.i32, shape=cap)
        self.x_ref = ti.Vector.field(3, float, shape=cap)  # positions at the last rebuild
        self.overflow = ti.field(ti.i32, shape=())
        #: melt dropped in the last rebuild (its position not finite), then melt outside the
        #: box, kept, and that melt by the face it is beyond (FACES order)
        self.lost_melt = ti.field(ti.i32, shape=())
        self.outside_melt = ti.field(ti.i32, shape=())
        self.outside_face = ti.field(ti.i32, shape=N_FACES)
        self.serial_scatter = current().get("arch", "cpu") == "cpu"
        self._overflow = 0
        self.lost_total = 0
        self.lost_last = {}  #: the last rebuild's dropped melt ({"not_finite": count})
        self.outside_last = {}  #: the last rebuild's melt outside the box, by face (FACES)
        self._reorder = None  # built on the first rebuild, once every module registered its fields

    @staticmethod
    def memory_bytes(n_cells: int, capacity: int, max_neighbours: int = 96) -> int:
        return 8 * n_cells + (8 + 4 + 4 * max_neighbours) * capacity

    # ------------------------------------------------------------- sorting
    @ti.func
    def cell_coords(self, x):
        """x's cell, clamped into the grid: a particle outside the domain's box is sorted into
        the nearest cell. Clamping moves no two cells further apart (per axis |clamp(a) -
        clamp(b)| <= |a - b|), so every neighbour within a query's reach of cells is still
        scanned, and the search stays exact: melt the nozzle carries past the box's edge keeps
        its neighbours instead of being dropped, at the cost of crowding the edge cells."""
        c = ti.Vector([0, 0, 0])
        dims = self.dims_f[None]
        for d in ti.static(range(3)):
            t = (x[d] - self.lo_f[None][d]) / self.cell
            t = ti.min(ti.max(t, 0.0), ti.cast(dims[d], float) - 0.5)  # before the cast
            c[d] = ti.cast(ti.floor(t), ti.i32)
        return c

    @ti.func
    def face_outside(self, x):
        """Index in FACES of the face of the domain's box that x is beyond (the last
        axis it is out along), -1 inside."""
        face = -1
        for d in ti.static(range(3)):
            t = (x[d] - self.lo_f[None][d]) / self.cell
            if t < 0.0:
                face = 2 * d
            elif t >= ti.cast(self.dims_f[None][d], float):
                face = 2 * d + 1
        return face

    # The whole rebuild is one generated kernel (see _make_rebuild): each stage below is a
    # ti.func whose loops sit at the kernel's top level, so Taichi parallelises them, and the
    # step pays for one launch instead of eight.
    @ti.func
    def _bin(self, n):
        self.lost_melt[None] = 0
        self.outside_melt[None] = 0
        for f in range(N_FACES):
            self.outside_face[f] = 0
        for c in range(self.n_alloc + 1):
            self.count[c] = 0
        for i in range(n):
            x = self.state.x[i]
            finite = True
            for d in ti.static(range(3)):
                finite = finite and not (ti.math.isnan(x[d]) or ti.math.isinf(x[d]))
            ph = self.state.phase[i]
            lin = self.dropped_bucket
            if finite:
                # the nozzle too: melt riding on it past the box keeps its wall (parked, the
                # nozzle left such melt free, and it fell: 1.73 m/s in test_idle's full run)
                c = self.cell_coords(x)
                dims = self.dims_f[None]
                lin = (c[0] * dims[1] + c[1]) * dims[2] + c[2]
                face = self.face_outside(x)
                if face >= 0 and ph <= SOLID:
                    ti.atomic_add(self.outside_melt[None], 1)
                    ti.atomic_add(self.outside_face[face], 1)
            elif ph <= SOLID:
                ti.atomic_add(self.lost_melt[None], 1)
            self.cell_of[i] = lin
            ti.atomic_add(self.count[lin], 1)

    @ti.func
    def _exclusive_scan(self, values: ti.template(), starts: ti.template(), length):
        """starts[k] = values[0] + ... + values[k-1] for k = 0..length, in 1024-wide blocks."""
        nb = (length + self.block - 1) // self.block
        for b in range(nb):
            s = 0
            for k in range(b * self.block, ti.min((b + 1) * self.block, length)):
                s += values[k]
            self.block_sum[b] = s
        ti.loop_config(serialize=True)
        for _ in range(1):
            run = 0
            for b in range(nb):
                v = self.block_sum[b]
                self.block_sum[b] = run
                run += v
            starts[length] = run
        for b in range(nb):
            run = self.block_sum[b]
            for k in range(b * self.block, ti.min((b + 1) * self.block, length)):
                starts[k] = run
                run += values[k]

    @ti.func
    def _scan(self):
        self._exclusive_scan(self.count, self.start, self.n_alloc + 1)
        for c in range(self.n_alloc + 1):
            self.count[c] = 0  # reused as the fill cursor by the scatter

    @ti.func
    def _scatter(self, n):
        if ti.static(self.serial_scatter):
            ti.loop_config(serialize=True)
            for i in range(n):
                c = self.cell_of[i]
                self.perm[self.start[c] + self.count[c]] = i
                self.count[c] += 1
        else:
            for i in range(n):
                c = self.cell_of[i]
                slot = ti.atomic_add(self.count[c], 1)
                self.perm[self.start[c] + slot] = i

    def rebuild(self):
        """Sort live particles by cell, permute all registered fields, rebuild the neighbour
        lists; return the number of melt particles dropped: those whose position is not
        finite (a blow-up; retired boundaries, NaN by design, are dropped uncounted). Melt
        outside the domain's box is kept (cell_coords) and counted in outside_last."""
        n = self.state.n
        if n == 0:
            return 0
        if self._reorder is None:
            self._reorder = _make_rebuild(self)
            self.state.frozen = True
        alive, lost, overflow, outside = (int(v) for v in self._reorder(n))
        self.state.n = alive
        self.lost_total += lost
        self.lost_last = {"not_finite": lost} if lost else {}
        self.outside_last = {}
        if outside:
            self.outside_last = {face: int(count) for face, count in
                                 zip(FACES, self.outside_face.to_numpy()) if count}
        self._overflow = overflow
        self.stale = False
        self.rebuilds += 1
        return lost

    def needs_rebuild(self, max_displacement_m: float) -> bool:
        """Lists are stale once a particle may have moved half the skin since the rebuild."""
        return self.stale or self.skin == 0.0 or max_displacement_m > 0.5 * self.skin

    @ti.func
    def displacement(self, i):
        """Distance particle i moved since the last rebuild."""
        return (self.state.x[i] - self.x_ref[i]).norm()

    def overflowed(self) -> int:
        """Particles whose neighbour list was truncated in the last rebuild."""
        return self._overflow

    @ti.func
    def row(self, i):
        """Where particle i's list starts in nbr."""
        r = i * self.max_neighbours
        if ti.static(self.packed):
            r = self.list_start[i]
        return r

    @ti.func
    def _count_task(self, i, j, xij, acc: ti.template()):
        acc += 1

    @ti.func
    def _own_list(self, i):
        """Particles that get a list whatever their neighbours: melt, and solidified melt
        where heat conducts through it; every other particle is a wall, listed where melt
        sees it."""
        ph = self.state.phase[i]
        own = ph == FLUID
        if ti.static(self.solid_lists):
            own = ph <= SOLID
        return own

    @ti.func
    def _flag_walls(self, j):
        if not self._own_list(j):
            self.wall_needed[j] = 1  # benign race: every writer stores 1

    @ti.func
    def _melt_count_task(self, i, j, xij, acc: ti.template()):
        self._flag_walls(j)
        acc += 1

    @ti.func
    def _list_task(self, i, j, xij, acc: ti.template()):
        if acc < self.max_neighbours:
            self.nbr[self.row(i) + acc] = j
        acc += 1

    @ti.func
    def _melt_list_task(self, i, j, xij, acc: ti.template()):
        if ti.static(not self.packed):  # packed lists: the count pass flagged the walls
            self._flag_walls(j)
        self._list_task(i, j, xij, acc)

    @ti.func
    def _list_pass(self, alive, walls: ti.template(), task: ti.template(), fill: ti.template()):
        """n_nbr of the melt (walls=False) or of the walls the melt flagged (True); fill:
        also write the lists (and count the truncated ones)."""
        for i in range(alive):
            wanted = self._own_list(i)
            if ti.static(walls):
                wanted = not wanted and self.wall_needed[i] == 1
            if wanted:
                acc = 0
                self.scan_cells(i, task, acc)
                if acc > self.max_neighbours:
                    if ti.static(fill):
                        ti.atomic_add(self.overflow[None], 1)
                    acc = self.max_neighbours
                self.n_nbr[i] = acc

    @ti.func
    def _build_lists(self):
        # Walls get a list only if some melt particle sees them: in a print most of the
        # plate is idle, and this costs one flag write per melt-wall pair.
        self.overflow[None] = 0
        alive = self.start[self.dropped_bucket]
        for i in range(alive):
            self.wall_needed[i] = 0
            self.n_nbr[i] = 0
        if ti.static(self.packed):
            self._list_pass(alive, False, self._melt_count_task, False)
            self._list_pass(alive, True, self._count_task, False)
            self._exclusive_scan(self.n_nbr, self.list_start, alive)
        self._list_pass(alive, False, self._melt_list_task, True)
        self._list_pass(alive, True, self._list_task, True)

    # ------------------------------------------------------------- queries
    @ti.func
    def for_each_neighbour(self, i, task: ti.template(), acc: ti.template()):
        """Call ``task(i, j, x_ij, acc)`` for every j != i with |x_i - x_j| < H
        (valid between rebuilds while particles move much less than H - cell size)."""
        xi = self.state.x[i]
        r = self.row(i)
        for k in range(self.n_nbr[i]):
            j = self.nbr[r + k]
            xij = xi - self.state.x[j]
            if xij.norm_sqr() < self.H * self.H:
                task(i, j, xij, acc)

    @ti.func
    def for_each_listed(self, i, task: ti.template(), acc: ti.template()):
        """Call ``task(i, slot, j, x_ij, acc)`` for every entry of i's list, within H or not:
        for solvers that cache per-pair values by list slot within one step (a cached value
        must be zero where |x_ij| >= H)."""
        xi = self.state.x[i]
        r = self.row(i)
        for k in range(self.n_nbr[i]):
            j = self.nbr[r + k]
            task(i, k, j, xi - self.state.x[j], acc)

    @ti.func
    def for_each_neighbour_partitioning(self, i, task: ti.template(), acc: ti.template()):
        """for_each_neighbour that also moves the neighbours within H to the front of i's list
        (a list stays a set, so reordering it is harmless). Later passes over the *same
        positions* then visit just those with for_each_support_neighbour: no distance test,
        no candidates from the skin, which a Verlet list holds ~50 % more of."""
        xi = self.state.x[i]
        r = self.row(i)
        m = 0
        slots = 0
        for k in range(self.n_nbr[i]):
            j = self.nbr[r + k]
            xij = xi - self.state.x[j]
            if xij.norm_sqr() < self.H * self.H:
                task(i, j, xij, acc)
                m += 1
                slots += k
        # Lists stay partitioned from pass to pass but for the few neighbours that crossed H,
        # so the swaps go to a second loop, run only when the m slots found are not 0..m-1
        # (distinct slots sum to m (m - 1) / 2 exactly then). Without stores the loop above
        # is one the compiler vectorises: the pass takes half the time, and its sum rounds
        # differently (f32 rounding, not physics).
        if 2 * slots != m * (m - 1):
            front = 0
            for k in range(self.n_nbr[i]):
                j = self.nbr[r + k]
                if (xi - self.state.x[j]).norm_sqr() < self.H * self.H:
                    self.nbr[r + k] = self.nbr[r + front]
                    self.nbr[r + front] = j
                    front += 1
        self.n_support[i] = m

    @ti.func
    def for_each_support_neighbour(self, i, task: ti.template(), acc: ti.template()):
        """The neighbours the last for_each_neighbour_partitioning pass found within H; valid
        only while positions are unchanged since that pass (e.g. later in the same kernel)."""
        xi = self.state.x[i]
        r = self.row(i)
        for k in range(self.n_support[i]):
            j = self.nbr[r + k]
            task(i, j, xi - self.state.x[j], acc)

    @ti.func
    def column(self, c, ox, oy, reach):
        """The sorted particles of the cells (c_x + ox, c_y + oy, c_z - reach .. c_z + reach),
        contiguous in the sorted arrays: their index range [lo, hi), empty outside the grid."""
        dims = self.dims_f[None]
        z0 = ti.max(c[2] - reach, 0)
        z1 = ti.min(c[2] + reach, dims[2] - 1)
        cx = c[0] + ox
        cy = c[1] + oy
        lo = 0
        hi = 0
        if 0 <= cx < dims[0] and 0 <= cy < dims[1] and z0 <= z1:
            col = (cx * dims[1] + cy) * dims[2]
            lo = self.start[col + z0]
            hi = self.start[col + z1 + 1]
        return ti.Vector([lo, hi])

    @ti.func
    def scan_cells(self, i, task: ti.template(), acc: ti.template()):
        """Like for_each_neighbour, but scanning the cells (used to build the lists)."""
        xi = self.state.x[i]
        c = self.cell_coords(xi)
        for dx in ti.static(range(-self.reach, self.reach + 1)):
            for dy in ti.static(range(-self.reach, self.reach + 1)):
                js = self.column(c, dx, dy, self.reach)
                for j in range(js[0], js[1]):
                    xij = xi - self.state.x[j]
                    if j != i and xij.norm_sqr() < self.R * self.R:
                        task(i, j, xij, acc)

    def neighbour_lists_numpy(self) -> list:
        """Neighbour indices of every live particle, sorted (test helper)."""
        n = self.state.n
        counts = self.n_nbr.to_numpy()[:n]
        flat = self.nbr.to_numpy()
        rows = self.list_start.to_numpy()[:n] if self.packed else np.arange(n) * self.max_neighbours
        return [np.sort(flat[rows[i]:rows[i] + counts[i]]) for i in range(n)]


def _make_rebuild(grid):
    """The rebuild kernel: bin, scan, scatter, gather every registered field through the
    permutation, build the lists. Fields are fixed once it exists."""
    state = grid.state
    perm = grid.perm
    fields = list(state.fields().values())
    temps = []
    for f in fields:
        if hasattr(f, "n"):
            temps.append(ti.Vector.field(f.n, f.dtype, shape=state.capacity))
        else:
            temps.append(ti.field(f.dtype, shape=state.capacity))
    nf = len(fields)

    @ti.kernel
    def rebuild(n: ti.i32) -> ti.types.vector(4, ti.i32):
        grid._bin(n)
        grid._scan()
        grid._scatter(n)
        for i in range(n):
            src = perm[i]
            for k in ti.static(range(nf)):
                temps[k][i] = fields[k][src]
        for i in range(n):
            for k in ti.static(range(nf)):
                fields[k][i] = temps[k][i]
            grid.x_ref[i] = state.x[i]
        grid._build_lists()
        return ti.Vector([grid.start[grid.dropped_bucket], grid.lost_melt[None], grid.overflow[None],
                          grid.outside_melt[None]])

    return rebuild
