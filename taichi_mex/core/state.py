"""Particle state: struct-of-arrays Taichi fields with a fixed capacity.

Live particles occupy indices ``0 .. n-1``. Each neighbour-grid rebuild sorts them by cell
(locality) and permutes *every registered field* with them, so physics modules register
the per-particle fields they own (warm starts, temperature, ...) via :meth:`add`.
Particles that leave the domain are dropped in that same sort and counted as lost.

Positions are stored relative to a local origin (``origin_m``) so that f32 keeps about
1e-9 m resolution on a 10 mm build region.
"""


import numpy as np

from taichi_mex.backend import real_np_dtype, ti
from taichi_mex.core.reduce import BLOCK

# phase codes: everything >= SOLID acts as a boundary for the fluid
FLUID = 0
SOLID = 1  # solidified melt: rigid, still conducts heat
PLATE = 2
NOZZLE = 3
INLET = 4  # melt inside the nozzle bore, moving with the prescribed inflow
PHASE_NAMES = {FLUID: "fluid", SOLID: "solid", PLATE: "plate", NOZZLE: "nozzle", INLET: "inlet"}

#: significant bits a field's length keeps (rounded up, shape_bucket). Taichi compiles each
#: field's shape, and each Python number a kernel reads, into the kernel: a run whose particle
#: capacity or grid differs from a cached run's by one entry compiles every kernel again (the
#: bundled bead at draft to print time 0.337 s, 2 cores: 119 kernels, 28 s of a 40 s run; 11 s
#: with them cached). Eight lengths an octave let runs of one G-code and spacing with other
#: end times, flows, speeds or materials share their kernels, at up to 12.5 % more memory.
SHAPE_BITS = 4


def shape_bucket(count: int) -> int:
    """The smallest integer >= count whose binary form has at most SHAPE_BITS significant
    bits (..., 8192, 9216, 10240, ...)."""
    count = max(int(count), 1)
    drop = max(count.bit_length() - SHAPE_BITS, 0)
    return -(-count >> drop) << drop


@ti.func
def is_fluid(phase):
    return phase == FLUID


@ti.func
def is_boundary(phase):
    return phase != FLUID


@ti.data_oriented
class ParticleState:
    """Core per-particle fields (SI units) and the registry of fields that move with sorts."""

    def __init__(self, capacity: int, origin_m=(0.0, 0.0, 0.0)):
        self.capacity = int(capacity)
        self.origin_m = np.asarray(origin_m, dtype=np.float64)
        self.n = 0  # live particles (host copy, updated by the grid)
        self.frozen = False  # set by the grid's first sort: no fields may be added after it
        self.on_append: list = []  # callbacks(slice, phase): the grid marks its lists stale, heat sets T
        self._fields: dict[str, object] = {}
        self.x = self.add("position", 3)  #: m, relative to origin_m
        self.v = self.add("velocity", 3)  #: m/s
        self.rho = self.add("density")  #: kg/m^3
        self.p = self.add("pressure")  #: Pa
        self.m = self.add("mass")  #: kg (boundary: rho0 * volume, see boundaries)
        self.phase = self.add("phase", dtype=ti.i32)
        self.bead = self.add("bead_id", dtype=ti.i32)  #: extruding interval, -1 for boundaries
        self.born = self.add("birth_time")  #: s, time the particle entered the domain
        #: a wall particle's depth under the wall's surface (m) and the surface's normal into
        #: the melt, where its geometry gives them (a plate, a nozzle's flat face); depth 0:
        #: not given (melt, solidified melt, a nozzle's flank)
        self.wall_depth = self.add("wall_depth")
        self.wall_normal = self.add("wall_normal", 3)

    def add(self, name: str, n: int = 1, dtype=None):
        """Allocate and register a per-particle field (n = 1 scalar, 3 vector)."""
        if self.frozen:
            raise RuntimeError(f"field {name!r} registered after the first neighbour sort")
        dtype = float if dtype is None else dtype
        if n == 1:
            f = ti.field(dtype, shape=self.capacity)
        else:
            f = ti.Vector.field(n, dtype, shape=self.capacity)
        self._fields[name] = f
        return f

    def fields(self) -> dict:
        return dict(self._fields)

    def nbytes_per_particle(self) -> int:
        return sum(_nbytes(f) for f in self._fields.values())

    # ----------------------------------------------------------- host access
    def numpy(self, name: str, phase: int | tuple | None = None) -> np.ndarray:
        """Copy of a field for the live particles (positions in absolute metres)."""
        arr = self._fields[name].to_numpy()[: self.n]
        if name == "position":
            arr = arr.astype(np.float64) + self.origin_m
        if phase is not None:
            arr = arr[np.isin(self.phase.to_numpy()[: self.n], np.atleast_1d(phase))]
        return arr

    def append(self, position_m: np.ndarray, phase: int, mass_kg, velocity_m_s=None,
               density=0.0, bead: int = -1, time_s: float = 0.0) -> slice:
        """Add particles at the end (between sorts); returns their index range."""
        k = len(position_m)
        if self.n + k > self.capacity:
            raise RuntimeError(f"particle capacity {self.capacity} exceeded")
        sl = slice(self.n, self.n + k)
        dt = real_np_dtype()
        vel = np.zeros((k, 3)) if velocity_m_s is None else np.broadcast_to(velocity_m_s, (k, 3))
        mass = np.broadcast_to(np.asarray(mass_kg, dtype=dt), (k,))
        if k:
            self._append(self.n, np.ascontiguousarray(position_m - self.origin_m, dtype=dt),
                         np.ascontiguousarray(vel, dtype=dt), np.ascontiguousarray(mass),
                         float(density), int(phase), int(bead), float(time_s))
        self.n += k
        if k:
            for callback in self.on_append:
                callback(sl, int(phase))
        return sl


    def zero_velocity(self, phase: int) -> None:
        """Set the velocity of every live particle of ``phase`` to zero."""
        self._zero_velocity(self.n, phase)

    @ti.kernel
    def _zero_velocity(self, n: ti.i32, phase: ti.i32):
        for i in range(n):
            if self.phase[i] == phase:
                self.v[i] = ti.Vector.zero(self.v.dtype, 3)

    @ti.kernel
    def _append(self, start: ti.i32, pos: ti.types.ndarray(), vel: ti.types.ndarray(),
                mass: ti.types.ndarray(), density: float, phase: ti.i32, bead: ti.i32,
                time_s: float):
        for k in range(pos.shape[0]):
            i = start + k
            for d in ti.static(range(3)):
                self.x[i][d] = pos[k, d]
                self.v[i][d] = vel[k, d]
            self.m[i] = mass[k]
            self.rho[i] = density
            self.p[i] = 0.0
            self.phase[i] = phase
            self.bead[i] = bead
            self.born[i] = time_s
            self.wall_depth[i] = 0.0
            self.wall_normal[i] = ti.Vector.zero(self.wall_normal.dtype, 3)

    def set_wall_surface(self, sl: slice, normal, depth_m) -> None:
        """The wall surface of particles ``sl`` (just appended): their depth under it (m,
        > 0) and its unit normal into the melt (one for all, or one per particle)."""
        k = sl.stop - sl.start
        if k == 0:
            return
        dt = real_np_dtype()
        nrm = np.ascontiguousarray(np.broadcast_to(np.asarray(normal, dtype=np.float64), (k, 3)), dtype=dt)
        dep = np.ascontiguousarray(np.broadcast_to(np.asarray(depth_m, dtype=np.float64), (k,)), dtype=dt)
        _write_vector(self.wall_normal, sl.start, nrm)
        _write_scalar(self.wall_depth, sl.start, dep)


@ti.kernel
def _write_scalar(f: ti.template(), start: ti.i32, values: ti.types.ndarray()):
    for k in range(values.shape[0]):
        f[start + k] = values[k]


@ti.kernel
def _write_vector(f: ti.template(), start: ti.i32, values: ti.types.ndarray()):
    for k in range(values.shape[0]):
        for d in ti.static(range(3)):
            f[start + k][d] = values[k, d]


def write_field(f, start: int, values: np.ndarray) -> None:
    """Write host values into a field from index ``start`` on."""
    if len(values) == 0:
        return
    values = np.ascontiguousarray(values)
    if values.ndim == 1:
        _write_scalar(f, start, values)
    else:
        _write_vector(f, start, values)


def _nbytes(f) -> int:
    per = 8 if f.dtype in (ti.f64, ti.i64) else 4
    n = f.n if hasattr(f, "n") else 1
    return per * n


@ti.data_oriented
class FluidIndex:
    """Indices of the fluid particles in storage order, for the solvers' loops.

    In a print the plate outnumbers the melt 1.2-10x; a CG iteration that loops over every
    particle spends most of its small loops skipping walls. Rebuild after every re-sort (the
    indices follow the storage order) and after phase changes."""

    def __init__(self, state: ParticleState):
        self.state = state
        self.index = ti.field(ti.i32, shape=state.capacity)
        #: all live particles: the solvers sum per-particle terms over this range (zero off
        #: the list), so their sums, and with them every iteration count, round as before
        self.total = ti.field(ti.i32, shape=())
        #: the list's entries for particles [b BLOCK, (b + 1) BLOCK) are
        #: index[block_start[b] .. block_start[b + 1]): a solver sums its rows block by block
        #: in one pass over the list, grouped exactly as a BlockSum over all live particles
        self.block_start = ti.field(ti.i32, shape=state.capacity // BLOCK + 2)
        self.n = 0

    @ti.kernel
    def _build(self, n: ti.i32) -> ti.i32:
        self.total[None] = n
        count = 0
        ti.loop_config(serialize=True)  # in order: the solvers' block sums stay deterministic
        for i in range(n):
            if i % BLOCK == 0:
                self.block_start[i // BLOCK] = count
            if self.state.phase[i] == FLUID:
                self.index[count] = i
                count += 1
        self.block_start[(n + BLOCK - 1) // BLOCK] = count
        return count

    def update(self) -> int:
        self.n = int(self._build(self.state.n))
        return self.n
