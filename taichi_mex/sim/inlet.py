"""The moving nozzle: an inlet column of melt in the bore, optionally the solid tip around it.

The melt inside the bore is a column of lattice *slices* that moves with the nozzle and
slides down at the inflow speed w(t) = Q(t) / A_lattice, where A_lattice is the lattice's
own cross-section (slice particle count x spacing^2). Its travel s(t) comes straight from
the selection's cumulative commanded volume, s = V(t) / A_lattice, so slice k crosses the
exit plane exactly when (k + 1/2) spacings of melt have been commanded: deposited mass
equals commanded mass to within half a slice at any instant, with no drift. Slices inside
the bore act as a moving boundary (supporting the fluid below them); below the exit plane
they become fluid. Like Genesis' emitter, particles come from the preallocated pool.
"""

import bisect

import numpy as np

from taichi_mex.backend import real_np_dtype, ti
from taichi_mex.sim.boundaries import column_slices, disc_lattice, nozzle_tip_lattice
from taichi_mex.core.state import FLUID, INLET, NOZZLE, SOLID


def fastest_wall_speed(velocity_m_s, slide_m_s):
    """Speed of the fastest particle the inlet moves (m/s), for one time or an array of them:
    the tip moves at the nozzle's velocity v, the column's particles at v - w z, sliding down
    the bore at w as the flow feeds them. |v| + w would overstate it by up to 41 % while the
    nozzle moves across the bore's axis, and shorten every step by as much."""
    v = np.asarray(velocity_m_s, dtype=np.float64)
    column = v - np.multiply.outer(np.asarray(slide_m_s, dtype=np.float64), [0.0, 0.0, 1.0])
    return np.maximum(np.linalg.norm(v, axis=-1), np.linalg.norm(column, axis=-1))


@ti.data_oriented
class NozzleInlet:
    def __init__(self, state, selection, spacing_m: float, support_radius_m: float,
                 particle_mass_kg: float, z_offset_m: float = 0.0,
                 tip_outer_diameter_m: float | None = None, flank_angle_deg: float | None = None,
                 body_height_m: float = 0.0):
        self.state = state
        self.selection = selection
        self.traj = selection.trajectory
        self.dx = float(spacing_m)
        self.particle_mass = float(particle_mass_kg)
        bore_r = 0.5e-3 * self.traj.printer.nozzle_diameter_mm
        self.slice_xy = disc_lattice(bore_r, self.dx)
        self.n_slice = len(self.slice_xy)
        self.area_lattice_m2 = self.n_slice * self.dx**2
        self.column_slices = column_slices(support_radius_m, self.dx)
        self.z_offset_m = float(z_offset_m)
        self.slices_spawned = 0
        self.slice_of = state.add("inlet_slice", dtype=ti.i32)
        self.offset = state.add("nozzle_offset", 3)
        self.released_count = 0
        self._ref = None  # nozzle tip and column travel at the last neighbour-list rebuild
        self._now = (np.zeros(3), 0.0)
        self._moved = False  # _now holds where advance() last put the nozzle
        self.speed = 0.0
        self.bead_intervals = self.traj.extruding_intervals()
        self._bead_starts = self.bead_intervals[:, 0].tolist()
        self.nozzle_particles = 0
        self._tip_outer_r = None if tip_outer_diameter_m is None else 0.5 * tip_outer_diameter_m
        self._bore_r = bore_r
        self._flank = flank_angle_deg
        self._body_height = float(body_height_m)

    # --------------------------------------------------------------- geometry
    def nozzle_state(self, time_s: float):
        """Tip position (m, absolute), velocity (m/s), inflow speed (m/s), travel s (m)."""
        pos_mm, vel_mm_s, flow, _, volume = self.selection.at(time_s)
        pos = np.array(pos_mm) * 1e-3 + np.array([0.0, 0.0, self.z_offset_m])
        vel = np.array(vel_mm_s) * 1e-3
        w = flow * 1e-9 / self.area_lattice_m2
        travel = volume * 1e-9 / self.area_lattice_m2
        return pos, vel, w, travel

    def bead_at(self, time_s: float) -> int:
        """Index of the extruding interval (bead) under way at time_s."""
        return max(bisect.bisect_right(self._bead_starts, time_s) - 1, 0)

    def particle_count_estimate(self) -> int:
        """Inlet column plus nozzle tip particles present at any time."""
        tip = 0
        if self._tip_outer_r is not None:
            tip = len(self._tip_offsets())
        return self.n_slice * (self.column_slices + 1) + tip

    def _tip_offsets(self) -> np.ndarray:
        return nozzle_tip_lattice(self._bore_r, self._tip_outer_r, self.dx, self.column_slices,
                                  self._flank, self._body_height)

    def build_tip(self, time_s: float) -> None:
        """Add the nozzle's solid tip: a flat annulus face and bore wall, as thick as the
        column, and its flank above it where one is given (boundaries.nozzle_tip_lattice)."""
        if self._tip_outer_r is None:
            return
        pos, vel, _, _ = self.nozzle_state(time_s)
        offsets = self._tip_offsets()
        sl = self.state.append(pos + offsets, NOZZLE, self.particle_mass, vel, density=0.0,
                               time_s=time_s)
        self._set_offsets(sl.start, offsets.astype(np.float64), -1)
        # the flat face's slab comes first (nozzle_tip_lattice), its depth under the face the
        # offset's height; the flank is left to Adami's ghost
        face = int(np.count_nonzero(offsets[:, 2] < self.column_slices * self.dx))
        self.state.set_wall_surface(slice(sl.start, sl.start + face), (0.0, 0.0, -1.0),
                                    offsets[:face, 2])
        self.nozzle_particles = len(offsets)

    def _set_offsets(self, start: int, offsets: np.ndarray, slice_index: int) -> None:
        self._write_offsets(start, np.ascontiguousarray(offsets, dtype=real_np_dtype()), slice_index)

    @ti.kernel
    def _write_offsets(self, start: ti.i32, offsets: ti.types.ndarray(), slice_index: ti.i32):
        for k in range(offsets.shape[0]):
            for d in ti.static(range(3)):
                self.offset[start + k][d] = offsets[k, d]
            self.slice_of[start + k] = slice_index

    # --------------------------------------------------------------- time step
    def advance(self, time_s: float) -> int:
        """Move nozzle and column to ``time_s``, release slices that left the bore, spawn new
        ones at the top. Returns the number of particles released as fluid."""
        pos, vel, w, travel = self.nozzle_state(time_s)
        while (self.slices_spawned + 0.5) * self.dx - travel < self.column_slices * self.dx:
            k = self.slices_spawned
            z = (k + 0.5) * self.dx - travel
            pts = np.hstack([self.slice_xy, np.zeros((self.n_slice, 1))])
            sl = self.state.append(pos + pts + np.array([0.0, 0.0, z]), INLET, self.particle_mass,
                                   vel + np.array([0.0, 0.0, -w]), density=0.0, time_s=time_s)
            self._set_offsets(sl.start, pts, k)
            self.slices_spawned += 1
        self._now = (pos, travel)
        self._moved = True
        self.speed = float(fastest_wall_speed(vel, w))
        o = self.state.origin_m
        released = self._move(self.state.n, pos[0] - o[0], pos[1] - o[1], pos[2] - o[2], vel[0],
                              vel[1], vel[2], w, travel, self.bead_at(time_s), time_s)
        self.released_count += released
        return released

    @ti.kernel
    def _move(self, n: ti.i32, px: float, py: float, pz: float, vx: float, vy: float, vz: float,
              w: float, travel: float, bead: ti.i32, time_s: float) -> ti.i32:
        released = 0
        tip = ti.Vector([px, py, pz])
        vel = ti.Vector([vx, vy, vz])
        for i in range(n):
            ph = self.state.phase[i]
            if ph == NOZZLE:
                self.state.x[i] = tip + self.offset[i]
                self.state.v[i] = vel
            elif ph == INLET:
                k = self.slice_of[i]
                z = (ti.cast(k, float) + 0.5) * self.dx - travel
                off = self.offset[i]
                self.state.x[i] = tip + ti.Vector([off[0], off[1], z])
                self.state.v[i] = vel + ti.Vector([0.0, 0.0, -w])
                if z < 0.0:
                    self.state.phase[i] = FLUID
                    self.state.bead[i] = bead
                    self.state.born[i] = time_s
                    released += 1
        return released

    def displacement_since_rebuild(self) -> float:
        """Upper bound on how far nozzle and column particles moved since the last rebuild."""
        if self._ref is None:
            return np.inf
        pos, travel = self._now
        return float(np.linalg.norm(pos - self._ref[0]) + abs(travel - self._ref[1]))

    def mark_rebuilt(self) -> None:
        self._ref = (self._now[0].copy(), self._now[1])

    @property
    def released_particles(self) -> int:
        return self.released_count

    @property
    def released_volume_m3(self) -> float:
        return self.released_particles * self.dx**3

    def melt_over_face(self) -> int:
        """Melt particles more than a spacing above the plane of the tip face, where the
        nozzle was last moved to. A print lays its melt under the face, so melt over it was
        either carried up on the nozzle (strings, blobs) or stands over the layer the nozzle
        prints, in its way (validation/blocks). 0 for a nozzle without a tip."""
        if self.nozzle_particles == 0 or not self._moved:  # no tip (build_tip adds none)
            return 0
        z = float(self._now[0][2] + self.dx - self.state.origin_m[2])
        return int(self._count_above(self.state.n, z))

    @ti.kernel
    def _count_above(self, n: ti.i32, z: float) -> ti.i32:
        count = 0
        for i in range(n):
            if (self.state.phase[i] == FLUID or self.state.phase[i] == SOLID) and self.state.x[i][2] > z:
                count += 1
        return count

    def retire(self) -> None:
        """Remove the column and tip (after the last deposition): they leave at the next sort."""
        self._retire(self.state.n)

    @ti.kernel
    def _retire(self, n: ti.i32):
        for i in range(n):
            if self.state.phase[i] == INLET or self.state.phase[i] == NOZZLE:
                self.state.x[i] = ti.Vector([ti.math.nan, ti.math.nan, ti.math.nan])
