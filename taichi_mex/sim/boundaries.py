"""Solid walls as particle lattices: the build plate and the nozzle tip."""

import math

import numpy as np


def plate_lattice(xmin_m: float, xmax_m: float, ymin_m: float, ymax_m: float, spacing_m: float,
                  layers: int) -> np.ndarray:
    """Cell-centred lattice under z = 0 (the plate surface): layer k at z = -(k + 1/2) dx.

    With fluid particles starting at z >= dx/2, the first fluid layer sits one spacing above
    the first wall layer, exactly as inside the fluid.
    """
    nx = max(1, int(round((xmax_m - xmin_m) / spacing_m)))
    ny = max(1, int(round((ymax_m - ymin_m) / spacing_m)))
    xs = xmin_m + (np.arange(nx) + 0.5) * spacing_m
    ys = ymin_m + (np.arange(ny) + 0.5) * spacing_m
    zs = -(np.arange(layers) + 0.5) * spacing_m
    X, Y, Z = np.meshgrid(xs, ys, zs, indexing="ij")
    return np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)


def disc_lattice(radius_m: float, spacing_m: float) -> np.ndarray:
    """(k, 2) square-lattice points inside a disc, centred on the origin.

    The lattice cross-section (k * dx^2) is what the inlet uses for flow bookkeeping, so
    the bore radius need not be a multiple of the spacing.
    """
    m = int(math.ceil(radius_m / spacing_m)) + 1
    ij = (np.arange(-m, m) + 0.5) * spacing_m
    X, Y = np.meshgrid(ij, ij, indexing="ij")
    pts = np.stack([X.ravel(), Y.ravel()], axis=1)
    inside = np.linalg.norm(pts, axis=1) < radius_m
    if not inside.any():  # coarser than the bore: one particle on the axis
        return np.zeros((1, 2))
    return pts[inside]


def annulus_lattice(inner_radius_m: float, outer_radius_m: float, spacing_m: float) -> np.ndarray:
    """(k, 2) lattice points with inner <= r < outer (the nozzle's flat tip face)."""
    m = int(math.ceil(outer_radius_m / spacing_m)) + 1
    ij = (np.arange(-m, m) + 0.5) * spacing_m
    X, Y = np.meshgrid(ij, ij, indexing="ij")
    pts = np.stack([X.ravel(), Y.ravel()], axis=1)
    r = np.linalg.norm(pts, axis=1)
    return pts[(r >= inner_radius_m) & (r < outer_radius_m)]


def column_slices(support_radius_m: float, spacing_m: float) -> int:
    """Slices of the bore's inlet column, and the tip slab's thickness in slices: a kernel's
    support and one more, so that melt leaving the bore sees a full column above it."""
    return int(math.ceil(support_radius_m / spacing_m)) + 1


def nozzle_tip_lattice(bore_radius_m: float, tip_radius_m: float, spacing_m: float,
                       face_slices: int, flank_angle_deg: float | None = None,
                       body_height_m: float = 0.0) -> np.ndarray:
    """(k, 3) offsets from the tip face's centre of the nozzle's solid: the flat face, an
    annulus from the bore to the tip radius, ``face_slices`` thick; above it, where a flank
    angle is given, the nozzle's cone up to ``body_height_m`` over the face. The flank rises
    at that angle from the face's plane, outward from the face's outer edge at the slab's
    top; the cone is a shell as thick, along its normal, as the slab (at least the kernel's
    support, so that melt on it sees a full wall)."""
    out = []
    ring = annulus_lattice(bore_radius_m, tip_radius_m, spacing_m)
    for k in range(face_slices):
        out.append(np.hstack([ring, np.full((len(ring), 1), (k + 0.5) * spacing_m)]))
    if flank_angle_deg is not None:
        top = face_slices * spacing_m
        angle = math.radians(flank_angle_deg)
        run_per_rise = math.cos(angle) / math.sin(angle)
        across = top / math.sin(angle)  # the shell's horizontal width
        k = face_slices
        while (k + 0.5) * spacing_m < body_height_m:
            z = (k + 0.5) * spacing_m
            outer = tip_radius_m + (z - top) * run_per_rise
            pts = annulus_lattice(max(bore_radius_m, outer - across), outer, spacing_m)
            out.append(np.hstack([pts, np.full((len(pts), 1), z)]))
            k += 1
    return np.concatenate(out) if out else np.zeros((0, 3))
